"""The record of one simulation run (the `Trajectory` returned by `vcirun.simulate`), its dense
output `tr(t)`, and its conversions (`to_xarray`, `to_dataframe`, `plot`).

Dense output. Between grid points (and between the impacts inside a step) the states are joined by
cubic Hermite interpolation of q and p, with the slopes (qdot, pdot) of the continuous dynamics at
the recorded states (`_dynamics`: the compiled, forced, Hamilton equations of the run's module). An impact
step k -> k+1 is split at its recorded impact states: [t_k, tau_1] ends in (q(tau_1), p-),
[tau_1, ...] starts from (q(tau_1), p+) (q+ of a declared reset map that moves q: a walker's leg
exchange), so no piece ever interpolates across a jump; the interpolant is right-continuous at an
impact (p+ at t = tau) and equals the grid state at every grid time. Its own error is O(h^4) per piece, so between grid points it keeps the method's order
for methods of order <= 4 (every method of the paper: order 2; CVA4); for CVA6/CVA8 it is limited to
order 4 between grid points (exact at them).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..core import record

# Status strings a run can end with (codes and meanings: vcirun.core.record.STATUSES). Failures are data:
# they carry the step, time and state.
OK, NEWTON_FAILED, EVENT_FAILED, RESET_FAILED, ACCUMULATION, NONFINITE, PAINLEVE = (name for name, _ in record.STATUSES)
STATUS_CODES = record.STATUS_CODES


# the record's rows every Trajectory has (empty where a run gave none), with their dtypes
_DEFAULTED = tuple((f.name, f, np.bool_ if f.dtype == "bool" else np.dtype(f.dtype)) for f in record.FIELDS
                   if f.only is None)


@dataclass
class Trajectory:
    method: str
    system: str
    h: float
    T: float
    t: np.ndarray
    status: str = OK
    message: str = ""
    fail_step: int = -1
    fail_time: float = float("nan")
    beta: float | None = None
    wall_time: float = 0.0
    tolerances: dict = field(default_factory=dict)
    options: dict = field(default_factory=dict)
    coordinates: list | None = None    # names of the n coordinates (None: q0 .. q{n-1})
    # (t, y) -> ydot of the continuous dynamics, for dense output; attached by simulate, dropped when
    # pickled (resolved again from a built-in scene's name, see `attach_dynamics`)
    dynamics: object = field(default=None, repr=False, compare=False)
    # what simulate was given as the system (a scene name, a YAML path or a MechanicalSystem): where
    # `animate` finds the drawing; pickled only as a name or path
    source: object = field(default=None, repr=False, compare=False)
    # the simulate call's arguments (vcirun.run.pilot.RunArgs), for the companions of error_estimate;
    # dropped when pickled (a trajectory without them re-runs a built-in scene from its first state)
    run_args: object = field(default=None, repr=False, compare=False)
    # simulate(tol=...): the choice of method and h (vcirun.run.choose.Choice), else None
    choice: object = field(default=None, repr=False, compare=False)
    # the kernels' tier ("compiled" or "interpreted") and the compiled module's build ("shared" or
    # "specialized"; None on the interpreted tier and where numba compiles nothing), as run; a
    # trajectory read from a file has what the file stored (None where it stored nothing)
    tier: str | None = field(default=None, compare=False)
    build: str | None = field(default=None, compare=False)
    # The run record: one field per row of vcirun.core.record.FIELDS, in its order (a test holds them
    # equal), written out so that editors and type checkers see them. None here; `__post_init__`
    # makes each an empty array of its row's dtype, except rows of some methods only (Hmod).
    q: np.ndarray | None = None
    p: np.ndarray | None = None
    H: np.ndarray | None = None
    Ed: np.ndarray | None = None
    Hmod: np.ndarray | None = None
    impacts: np.ndarray | None = None
    impact_q: np.ndarray | None = None
    impact_p_minus: np.ndarray | None = None
    impact_p_plus: np.ndarray | None = None
    impact_impulse: np.ndarray | None = None
    impact_contact: np.ndarray | None = None
    impact_step: np.ndarray | None = None
    partial_steps: np.ndarray | None = None
    newton_iters: np.ndarray | None = None
    contact_active: np.ndarray | None = None
    contact_force: np.ndarray | None = None
    releases: np.ndarray | None = None
    release_contact: np.ndarray | None = None
    impact_impulse_t: np.ndarray | None = None
    contact_mode: np.ndarray | None = None
    friction_work: np.ndarray | None = None
    mode_changes: np.ndarray | None = None
    mode_change_contact: np.ndarray | None = None
    mode_change_kind: np.ndarray | None = None

    def __post_init__(self):
        d = self.__dict__
        n = None
        for name, f, dt in _DEFAULTED:
            if d[name] is None:
                if n is None:
                    n = self.q.shape[1] if isinstance(self.q, np.ndarray) and self.q.ndim == 2 else 0
                d[name] = np.zeros(f.shape(0, n, 0), dt)

    @classmethod
    def of_run(cls, values: dict, derive=None, complete: bool = False) -> "Trajectory":
        """The Trajectory of a finished run: `values` holds method, system, h, T, t, tolerances, options
        and every record row (None only for a row of some methods only, Hmod), as `__init__` takes
        them; the other fields take their defaults. The same object as `Trajectory(**values)`, built
        without the per-field pass of `__post_init__` (every row is given: `RUN_FIELDS` names what a
        run gives, and a test holds `vcirun.run.api.trajectory_of` to it).

        derive: a function name -> value for the fields that follow from the call alone (`DERIVED`:
        the grid times, tolerances, options, dynamics, run_args, each record the run left empty, the
        friction rows of a module without friction) that `values` leaves out. Each is made on its
        first read and kept, so a call pays only for what its caller reads
        (`vcirun.run.api.trajectory_of`). Pickling makes them all first. complete: `values` already
        holds every other field (it started from `run_defaults()`) and becomes the object's dict."""
        obj = cls.__new__(cls)
        if complete:
            values["_derive"] = derive
            obj.__dict__ = values
            return obj
        d = obj.__dict__
        if derive is None:
            d.update(_DEFAULTS)
        else:
            d.update(_UNDERIVED_DEFAULTS)
            d["_derive"] = derive
        d.update(values)
        return obj

    def _settle(self) -> None:
        """Make every derived field that is not made yet (`of_run`'s derive), and drop the derive."""
        if "_derive" in self.__dict__:
            for name in DERIVED:
                getattr(self, name)
            del self.__dict__["_derive"]

    @property
    def ok(self) -> bool:
        return self.status == OK

    def __getstate__(self):
        self._settle()
        state = dict(self.__dict__)
        state["dynamics"] = None
        if not isinstance(state.get("source"), (str, type(None))):
            state["source"] = str(state["source"]) if hasattr(state["source"], "__fspath__") else None
        state["run_args"] = None
        state.pop("_dense", None)
        state.pop("_account", None)
        state.pop("_qdot", None)
        return state

    # --- error estimate ---------------------------------------------------------------------------
    def error_estimate(self, kind: str = "richardson", *, companions: int = 1, reference=None, system=None,
                       grazing: bool = True, check_order: bool = True):
        """The estimated error of this run (vcirun.run.estimate.ErrorEstimate): its L2 error on the grid
        (the norm of `vcirun.l2_error`), with bounds, and the final-state errors.

        kind "richardson": a companion run of the same method from the same start at h / 2, the method's
        verified order, and a third run (2h where N is even and that run resolves the motion, else
        h / 4; companions=2: h / 4) whose observed order must be within one of it (check_order=False
        skips the third run);
        kind "reference" (or reference= a `vcirun.reference`): against the exact reference.
        status "unresolved" (no number) where the runs' impact sequences differ, an impact lies near
        the end within the runs' disagreement, or a contact grazes between grid points; "failed"
        where a run did not finish. A run of `simulate(tol=...)` carries the estimate its choice made (`choice.estimate`); this computes a new one.
        system: the YAML path or MechanicalSystem of a trajectory read from a file."""
        from .estimate import estimate

        return estimate(self, kind=kind, companions=companions, reference=reference, system=system,
                        grazing=grazing, check_order=check_order)

    # --- dense output -----------------------------------------------------------------------------
    @property
    def coordinate_names(self) -> list[str]:
        from ..scenes.registry import coordinate_names

        return coordinate_names(self.system, self.q.shape[1], self.coordinates)

    def attach_dynamics(self, system=None, params=None) -> "Trajectory":
        """Attach the continuous dynamics dense output needs (a trajectory read from a results file or
        unpickled has none): `system` a built-in name, YAML path or MechanicalSystem (default: this
        run's system name, which works for built-in scenes); `params` default: the run's. Returns self."""
        from ..codegen.kernel_set import SYSTEM_KERNELS
        from .resolve import resolve_numeric

        sysd, load, _ = resolve_numeric(self.system if system is None else system, SYSTEM_KERNELS)
        prm = sysd.param_values(params if params is not None else (self.options or {}).get("params"))
        self.dynamics = _dynamics(load(), prm)
        if system is not None:   # (only once it resolved: a refused system does not stay on the trajectory)
            self.source = system
        self.__dict__.pop("_dense", None)
        self.__dict__.pop("_account", None)
        return self

    def _dense_output(self) -> "DenseOutput":
        d = self.__dict__.get("_dense")
        if d is None:
            if len(self.t) == 0:
                raise ValueError("dense output: this trajectory holds no grid states (stored with "
                                 "store_trajectories: false?)")
            if self.dynamics is None:
                from ..scenes.registry import scene_info

                if scene_info(self.system) is None:
                    raise ValueError(f"dense output: the dynamics of system {self.system!r} are not attached; "
                                     "call tr.attach_dynamics(system) with its YAML path or MechanicalSystem")
                self.attach_dynamics()
            d = DenseOutput(self, self.dynamics)
            self.__dict__["_dense"] = d
        return d

    def __call__(self, t) -> np.ndarray:
        """q(t) by dense output: shape (n,) for a scalar t, (len(t), n) for an array. ValueError for t
        outside [t_0, t_N] (no extrapolation)."""
        return self._dense_output().state(t)[..., : self.q.shape[1]]

    def momentum(self, t) -> np.ndarray:
        """p(t) by dense output (right-continuous at impacts); shapes as `tr(t)`."""
        return self._dense_output().state(t)[..., self.q.shape[1]:]

    def state(self, t) -> np.ndarray:
        """(q(t), p(t)) concatenated: shape (2n,) or (len(t), 2n)."""
        return self._dense_output().state(t)

    def velocity(self, t) -> np.ndarray:
        """qdot(t) = M(q(t))^-1 p(t) by dense output (right-continuous at impacts); shapes as `tr(t)`."""
        y = np.atleast_2d(self.state(t))
        out = self._velocities(y)
        return out[0] if np.ndim(t) == 0 else out

    @property
    def qdot(self) -> np.ndarray:
        """Velocities qdot_k = M(q_k)^-1 p_k at the grid states, (N+1, n) (needs the dynamics, as dense
        output; computed on first use)."""
        v = self.__dict__.get("_qdot")
        if v is None:
            v = self.__dict__["_qdot"] = self._velocities(np.hstack([self.q, self.p]))
        return v

    def _velocities(self, Y) -> np.ndarray:
        if self.dynamics is None:
            self._dense_output()   # attaches the dynamics of a built-in scene, or says how
        n = self.q.shape[1]
        return np.array([self.dynamics(0.0, y)[:n] for y in Y]).reshape(len(Y), n)

    # --- conversions ------------------------------------------------------------------------------
    def _units(self) -> tuple[list, list, str]:
        from ..scenes.registry import momentum_unit, scene_info, units_for

        names = self.coordinate_names
        qu = units_for(self.system, names)
        return qu, [momentum_unit(u) for u in qu], "J" if scene_info(self.system) is not None else ""

    def to_xarray(self):
        """An xarray.Dataset: q, p over (t, coordinate) with the system's coordinate names, H, Ed,
        Hmod over t, the impact record over `impact`; units as attributes (SI, built-in scenes) and
        per coordinate in the `q_units` / `p_units` coordinates; run facts as Dataset attributes."""
        import xarray as xr

        names = self.coordinate_names
        qu, pu, eu = self._units()
        coords = {"t": ("t", np.asarray(self.t, float), {"units": "s", "long_name": "time"}),
                  "coordinate": ("coordinate", names), "q_units": ("coordinate", qu),
                  "p_units": ("coordinate", pu),
                  "impact": ("impact", np.arange(len(self.impacts)))}
        data = {
            "q": (("t", "coordinate"), self.q, {"long_name": "generalized coordinates (grid states)"}),
            "p": (("t", "coordinate"), self.p, {"long_name": "generalized momenta p = M(q) qdot"}),
            "H": ("t", self.H, {"units": eu, "long_name": "Hamiltonian H(q, p)"}),
            "Ed": ("t", self.Ed, {"units": eu, "long_name": "discrete energy -D3 Ld of the trial full step"}),
            "impact_step": ("step", np.asarray(self.impact_step, bool),
                            {"long_name": "step k -> k+1 contained an impact"}),
            "newton_iters": ("step", np.asarray(self.newton_iters), {"long_name": "Newton iterations of step k"}),
            "impact_time": ("impact", self.impacts, {"units": "s"}),
            "impact_q": (("impact", "coordinate"), self.impact_q.reshape(len(self.impacts), len(names))),
            "impact_p_minus": (("impact", "coordinate"), self.impact_p_minus.reshape(len(self.impacts), len(names))),
            "impact_p_plus": (("impact", "coordinate"), self.impact_p_plus.reshape(len(self.impacts), len(names))),
        }
        if self.Hmod is not None:
            data["Hmod"] = ("t", self.Hmod, {"units": eu, "long_name": "truncated modified Hamiltonian"})
        attrs = {"system": self.system, "method": self.method, "h": self.h, "T": self.T, "status": self.status,
                 "message": self.message, "wall_time": self.wall_time,
                 "beta": np.nan if self.beta is None else float(self.beta)}
        if len(self.newton_iters) != len(self.t) - 1:
            data.pop("impact_step"), data.pop("newton_iters")
        return xr.Dataset(data, coords=coords, attrs=attrs)

    def to_dataframe(self):
        """A pandas DataFrame, one row per grid point: t, each coordinate by name, p_<name>, H, Ed
        (Hmod); units in `df.attrs["units"]`."""
        import pandas as pd

        names = self.coordinate_names
        qu, pu, eu = self._units()
        cols = {"t": self.t}
        cols.update({c: self.q[:, i] for i, c in enumerate(names)})
        cols.update({f"p_{c}": self.p[:, i] for i, c in enumerate(names)})
        cols.update(H=self.H, Ed=self.Ed)
        if self.Hmod is not None:
            cols["Hmod"] = self.Hmod
        df = pd.DataFrame(cols)
        df.attrs["units"] = {"t": "s", **dict(zip(names, qu)), **{f"p_{c}": u for c, u in zip(names, pu)},
                             "H": eu, "Ed": eu, "Hmod": eu}
        df.attrs.update(system=self.system, method=self.method, h=self.h, status=self.status)
        return df

    def save(self, path):
        """Write the run to `path` by its suffix: .h5/.hdf5 (group `trajectory`, the layout of a results
        file's run group; read back with `vcirun.run.trajectory.read_trajectory`), .nc (netCDF via
        `to_xarray`, needs h5netcdf or netCDF4), .csv (`to_dataframe`), .npz (numpy arrays)."""
        from pathlib import Path

        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".h5", ".hdf5", ".nc", ".csv", ".npz"):
            raise ValueError(f"output: unknown format {path.suffix or '(none)'!r} of {path}; use .h5, .nc, .csv or .npz")
        path.parent.mkdir(parents=True, exist_ok=True)
        if suffix in (".h5", ".hdf5"):
            import h5py

            from . import trajectory_files

            attrs, arrays = trajectory_files.trajectory_payload(self)
            attrs["coordinates"] = self.coordinate_names
            with h5py.File(path, "w", libver=trajectory_files.LIBVER) as f:
                f.attrs["format"] = trajectory_files.fixed_text("vcirun-trajectory")
                trajectory_files.write_group(f, "trajectory", {k: v for k, v in attrs.items() if k != "coordinates"}, arrays)
                f["trajectory"].attrs["coordinates"] = trajectory_files.fixed_texts(self.coordinate_names)
        elif suffix == ".nc":
            self.to_xarray().to_netcdf(path)
        elif suffix == ".csv":
            self.to_dataframe().to_csv(path, index=False)
        else:
            arrays = {k: np.asarray(getattr(self, k)) for k in ("t", "q", "p", "H", "Ed", "impacts", "impact_q",
                                                                "impact_p_minus", "impact_p_plus", "impact_step")}
            if self.Hmod is not None:
                arrays["Hmod"] = self.Hmod
            np.savez(path, coordinates=np.array(self.coordinate_names), **arrays)
        return path

    def plot(self, dense: bool = True, samples_per_step: int = 8):
        """A matplotlib Figure: each coordinate against time (the dense output as a line when the
        dynamics are available, grid states as dots), impacts as dashed lines, and H (and Hmod).
        The Figure is not registered with pyplot and no global matplotlib state changes."""
        from .plotting import trajectory_figure

        return trajectory_figure(self, dense=dense, samples_per_step=samples_per_step)

    def animate(self, path=None, *, system=None, fps=30, speed=None, max_frames=600, energy=True, dpi=100):
        """An animation of the run (vcirun.run.animate.Animation): the mechanism drawn from the scene's
        geometry (bodies-form scenes, built-in scenes, a YAML `draw:` section; else configuration space),
        impacts marked, the energy beside it, a time bar. path: write .mp4 (ffmpeg) or .gif (Pillow);
        in a notebook the returned object displays itself. system: the scene (default: the run's, for
        built-in scenes; a YAML path for others); speed: motion seconds per second (default 1, raised to
        fit max_frames)."""
        from .animate import animate

        return animate(self, path, system=system, fps=fps, speed=speed, max_frames=max_frames, energy=energy, dpi=dpi)

    def energy_account(self):
        """Where the energy went: H(t) - H(t0) split into the impact law's loss (restitution, plastic
        holds), the forcing work and the rest, the integration error (`account.error`: its largest
        magnitude). A `vcirun.run.accounts.EnergyAccount`; `print(account)` shows the table. Needs the
        dynamics (attached for built-in scenes; else `attach_dynamics(system)` first)."""
        from .accounts import trajectory_account

        acc = self.__dict__.get("_account")
        if acc is None:
            acc = self.__dict__["_account"] = trajectory_account(self)
        return acc

    @property
    def n_steps(self) -> int:
        return len(self.t) - 1

    def __repr__(self) -> str:
        return (f"Trajectory(method={self.method!r}, system={self.system!r}, h={self.h:g}, T={self.T:g}, "
                f"steps={self.n_steps}, impacts={len(self.impacts)}, status={self.status!r})")


_SIZES = {"grid": "N+1", "step": "N", "impact": "K_i", "partial": "K_p", "release": "K_r", "mode": "K_m"}
Trajectory.__doc__ = (
    "Time-major record of a run on the grid t_k = t0 + k h (N = grid steps taken, n = degrees of freedom,\n"
    "m = constraints, K_i impacts, K_p partial steps, K_r releases, K_m mode changes). t (N+1,) grid times; the arrays, one\n"
    "per vcirun.core.record.FIELDS row:\n"
    + "\n".join(f"  {f.name} ({_SIZES[f.axis]}{', n' if f.dof else ''}{', m' if f.contacts else ''}"
                f"{',' if not (f.dof or f.contacts) else ''}) {f.dtype}: {f.doc}"
                + (" (None for other methods)" if f.only == "modified" else "") for f in record.FIELDS)
    + "\nand status, message, fail_step, fail_time, beta, wall_time, tolerances, options.")


def trajectory_from_group(g):
    """Rebuild a `Trajectory` from a run group (arrays that were not stored come back empty)."""
    from . import trajectory_files

    a = trajectory_files.decode_attrs(g.attrs)
    n = int(g["impact_q"].shape[1]) if "impact_q" in g and g["impact_q"].ndim == 2 else 0

    def arr(name, shape=(0,), dtype=float):
        return g[name][()] if name in g else np.zeros(shape, dtype)

    beta = a.get("beta", float("nan"))
    arrays = {}
    for f in record.FIELDS:  # one per row of the run record; a row not stored comes back empty
        if f.only is not None:
            arrays[f.name] = g[f.name][()] if f.name in g else None
            continue
        if f.name in record.FRICTION_ROWS and f.name not in g and a.get("friction_rows") is False:
            # left out where the run had no friction data: its fill values, as the run had them
            arrays[f.name] = trajectory_files.friction_fill(f.name, g, a.get("n_contacts"))
            continue
        dt = np.uint8 if f.dtype == "bool" else np.dtype(f.dtype)
        value = arr(f.name, f.shape(0, n, 0), dt)
        arrays[f.name] = value.astype(bool) if f.dtype == "bool" else value
    return Trajectory(
        method=a.get("core_method", a.get("method", "")), system=a.get("system", ""), h=float(a["h"]),
        T=float(a["T"]), t=arr("t"), **arrays,
        status=a.get("status", ""), message=a.get("message", ""), fail_step=int(a.get("fail_step", -1)),
        fail_time=float(a.get("fail_time", float("nan"))),
        beta=None if beta is None or not np.isfinite(beta) else float(beta), wall_time=float(a.get("wall_time", 0.0)),
        tolerances=a.get("tolerances") or {}, options=a.get("options") or {}, tier=a.get("tier") or None,
        build=a.get("build") or None)


def read_trajectory(path) -> Trajectory:
    """A Trajectory saved by `Trajectory.save(... .h5)` (dense output re-attaches for built-in scenes)."""
    import h5py

    with h5py.File(path, "r") as f:
        if "trajectory" not in f:
            raise ValueError(f"{path}: no 'trajectory' group (written by Trajectory.save / vcirun simulate --output?)")
        tr = trajectory_from_group(f["trajectory"])
        c = f["trajectory"].attrs.get("coordinates")
        if c is not None:
            tr.coordinates = [x.decode() if isinstance(x, bytes) else str(x) for x in c]
    return tr


class _Derived:
    """A Trajectory field that a run's `derive` makes on its first read (Trajectory.of_run); a value in
    the instance's dict (every Trajectory made by `__init__`, and each field once read or assigned)
    comes first, as for any non-data descriptor. Read on the class: the field's default."""

    __slots__ = ("name", "default")

    def __init__(self, name: str, default):
        self.name, self.default = name, default

    def __get__(self, obj, owner=None):
        if obj is None:
            return self.default
        d = obj.__dict__
        derive = d.get("_derive")
        v = d[self.name] = self.default if derive is None else derive(self.name)
        return v


# the fields a run's derive may leave to their first read: those that follow from the call alone, the
# records (a record a run left empty is a new empty array of its row's dtype and shape) and the friction
# rows (zeros where the module has no friction; so are the records' tangential impulses)
DERIVED = ("t", "tolerances", "options", "dynamics", "run_args", "contact_mode", "friction_work") + tuple(
    f.name for f in record.FIELDS if f.axis not in ("grid", "step"))
for _f in dataclasses.fields(Trajectory):
    if _f.name in DERIVED:
        setattr(Trajectory, _f.name, _Derived(_f.name, None if _f.default is dataclasses.MISSING else _f.default))

# Trajectory.of_run: the defaults of the fields with one, and the fields a run must give (RUN_FIELDS)
_DEFAULTS = {f.name: f.default for f in dataclasses.fields(Trajectory) if f.default is not dataclasses.MISSING}
_UNDERIVED_DEFAULTS = {k: v for k, v in _DEFAULTS.items() if k not in DERIVED}
RUN_FIELDS = frozenset(f.name for f in dataclasses.fields(Trajectory)
                        if f.default is dataclasses.MISSING or f.name in ("tolerances", "options")
                        or (f.name in record.FIELD and record.FIELD[f.name].only is None))


def run_defaults() -> dict:
    """A new dict of the defaults of the fields a run's derive does not make (Trajectory.of_run)."""
    return dict(_UNDERIVED_DEFAULTS)


def _dynamics(mod, prm):
    """The continuous right-hand side (t, y) -> ydot, y = (q, p), of a compiled module at parameters
    `prm`, for dense output: the one place that chooses it. The forced Hamilton equations
    (`dynamics_rhs`: pdot = -dH/dq + f(q, qdot, t); every module has it, vcirun.codegen.roles.ENTRY)."""
    prm = np.ascontiguousarray(prm, dtype=float)
    rhs = mod.dynamics_rhs

    def f(t, y):
        out = np.empty(y.shape[0])
        rhs(float(t), np.ascontiguousarray(y, dtype=float), prm, out)
        return out

    f.module, f.prm = mod, prm   # for the energy account (vcirun.run.accounts)
    return f


def _post_impact_q(traj, rhs, iq, ipm):
    """The configuration after each impact: q itself, except where the system declares a reset map
    that moves q (a walker's leg exchange): the map's q+ from the recorded (q, p-), as the loop computes
    it (the impact law's direction first, then vcirun.collision.declared's map)."""
    mod = getattr(rhs, "module", None)
    if mod is None or not bool(getattr(mod, "RESET_MAP", False)) or len(iq) == 0:
        return iq
    n, m = iq.shape[1], int(mod.NCON)
    prm = rhs.prm
    event_tol = float((traj.tolerances or {}).get("event_tol", 1e-13))
    out = iq.copy()
    d, lam, active = np.empty(n), np.empty(m), np.empty(m, np.int64)
    qn, pmap = np.empty(n), np.empty(n)
    for k in range(len(iq)):
        q, pm = np.ascontiguousarray(iq[k]), np.ascontiguousarray(ipm[k])
        c, s0, _ = mod.impact_direction(q, pm, float(traj.h), event_tol, prm, d, lam, active)
        if c > 0:
            mod.declared_reset(q, pm, d, s0, prm, qn, pmap)
            out[k] = qn
    return out


class DenseOutput:
    """Piecewise cubic Hermite interpolant of a Trajectory's states (see the module docstring).

    Nodes are the grid states and, inside impact steps, the impact states; node i carries the state
    arriving at it (left) and the one leaving it (right): equal at grid points, (q, p-) and (q, p+) at
    impacts. Piece i joins the right state of node i to the left state of node i+1. Slopes are
    evaluated lazily, only at the nodes of the pieces asked for."""

    def __init__(self, traj: Trajectory, rhs):
        t = np.asarray(traj.t, float)
        Y = np.hstack([traj.q, traj.p])
        self.n2 = Y.shape[1]
        self.rhs = rhs
        self.t_grid = t
        self.Y_grid = Y
        imp = np.asarray(traj.impacts, float)
        keep = (imp >= t[0]) & (imp <= t[-1])   # a failed run may record impacts of its last step
        imp = imp[keep]
        iq, ipm, ipp = (np.asarray(a, float).reshape(-1, traj.q.shape[1])[keep]
                        for a in (traj.impact_q, traj.impact_p_minus, traj.impact_p_plus))
        iq_plus = _post_impact_q(traj, rhs, iq, ipm)
        # step of each impact: (t_k, t_k+1] -> k (an impact exactly at t_k closes step k-1)
        step = np.clip(np.searchsorted(t, imp, side="left") - 1, 0, max(len(t) - 2, 0))
        # order: grid node k, then the impacts of step k by time
        key_step = np.concatenate([np.arange(len(t)), step])
        key_kind = np.concatenate([np.zeros(len(t)), np.ones(len(imp))])
        times = np.concatenate([t, imp])
        order = np.lexsort((times, key_kind, key_step))
        self.times = times[order]
        left = np.vstack([Y, np.hstack([iq, ipm])])[order]
        right = np.vstack([Y, np.hstack([iq_plus, ipp])])[order]
        self.left, self.right = left, right
        self.is_grid = (key_kind[order] == 0)
        self.FL = np.full_like(left, np.nan)
        self.FR = np.full_like(right, np.nan)
        a, b = self.times[:-1], self.times[1:]
        self.pieces = np.flatnonzero(b > a)      # zero-length pieces (an impact at a grid time) skipped
        self.starts = a[self.pieces]

    def _slopes(self, nodes, which):
        F, Y = (self.FL, self.left) if which == "left" else (self.FR, self.right)
        for i in nodes[~np.isfinite(F[nodes, 0])] if len(nodes) else nodes:
            F[i] = self.rhs(self.times[i], Y[i])
            if self.is_grid[i]:  # one state: one evaluation for both sides
                (self.FR if which == "left" else self.FL)[i] = F[i]
        return F[nodes]

    def state(self, t) -> np.ndarray:
        scalar = np.ndim(t) == 0
        tt = np.atleast_1d(np.asarray(t, float)).ravel()
        t0, t1 = self.t_grid[0], self.t_grid[-1]
        tol = 1e-12 * max(1.0, abs(t0), abs(t1))
        bad = ~((tt >= t0 - tol) & (tt <= t1 + tol))
        if bad.any():
            raise ValueError(f"t: {tt[bad][0]:.17g} is outside the trajectory's time span [{t0:g}, {t1:.17g}] "
                             "(dense output does not extrapolate)")
        if len(self.pieces) == 0:   # a single grid point
            out = np.repeat(self.right[:1], tt.size, axis=0)
        else:
            j = np.clip(np.searchsorted(self.starts, tt, side="right") - 1, 0, len(self.pieces) - 1)
            i = self.pieces[j]
            uniq = np.unique(i)
            self._slopes(uniq, "right")
            self._slopes(uniq + 1, "left")
            a, b = self.times[i], self.times[i + 1]
            d = (b - a)[:, None]
            s = ((tt - a) / (b - a))[:, None]
            y0, y1 = self.right[i], self.left[i + 1]
            m0, m1 = self.FR[i] * d, self.FL[i + 1] * d
            s2, s3 = s * s, s * s * s
            out = ((2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * y1
                   + (s3 - s2) * m1)
            # at the grid times: the grid states themselves (bit for bit)
            g = np.searchsorted(self.t_grid, tt)
            g = np.clip(g, 0, len(self.t_grid) - 1)
            hit = self.t_grid[g] == tt
            if hit.any():
                out[hit] = self.Y_grid[g[hit]]
        return out[0] if scalar else out
