"""The record of a run, as one table: what the compiled loop fills, what `Trajectory` holds, what a
results file stores, and what docs/reference/results_schema.md lists.

- FIELDS: every array the loop writes (name, axis, per-coordinate?, dtype, fill, storage, meaning).
  The generated module gets one index constant O_<NAME> per row (vcirun.codegen.units), the loop
  reads its output arrays as `out[O_<NAME>]` from one tuple built here (`allocate`), `Trajectory`
  has one attribute per row (trimmed by `trim`), and storage writes every row whose `stored` says so.
  Adding an array is one row here plus the kernel code that fills it; the memory estimate of a run
  and the stored size of its results (vcirun.core.sizes) are sums over these rows.
- AXES and `axis_rows`: the length of every axis, from N and the impact record's capacity
  (`impact_capacity`): the buffers `allocate` makes, and the rows those estimates count.
- COUNTERS: the loop's scalar results (status, where it stopped, how much it filled), the `info`
  array, indexed by I_<NAME>.
- SETTINGS: the loop's scalar inputs (the constraint switch and the tolerances), one float64 array,
  indexed by S_<NAME>.
- STATUSES: the status codes, in code order (ST_<NAME> in the module).

numpy only: importing this imports neither sympy nor numba.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

AXES = {
    "grid": "N+1 grid states t_k = t0 + k h",
    "step": "N grid steps k -> k+1",
    "impact": "one entry per impact, in time order",
    "partial": "one entry per partial step of Algorithm 1",
    "release": "one entry per release of a held contact, in time order",
    "mode": "one entry per change of a held contact's friction mode (slip, stick), in time order",
}


@dataclass(frozen=True)
class Field:
    """One array of the record. axis: a key of AXES; dof: a trailing axis of length n; contacts: a
    trailing axis of length m (one per constraint); fill: the value the buffer starts with (None:
    np.empty, the loop writes every entry that is read back); stored: "impacts" (always stored),
    "trajectory" (stored with store_trajectories), "no"; only: None, or "modified" (the MCVA family;
    None in the Trajectory of other methods)."""

    name: str
    axis: str
    dof: bool
    dtype: str
    fill: float | None
    stored: str
    doc: str
    only: str | None = None
    contacts: bool = False

    def shape(self, rows: int, n: int, m: int) -> tuple:
        return (rows,) + ((n,) if self.dof else ()) + ((m,) if self.contacts else ())

    @property
    def index_name(self) -> str:
        return "O_" + self.name.upper()

    @property
    def itemsize(self) -> int:
        """Bytes per entry, in memory and in a results file (bool: one byte)."""
        return 1 if self.dtype == "bool" else np.dtype(self.dtype).itemsize


FIELDS = (
    Field("q", "grid", True, "float64", None, "trajectory", "grid positions q_k"),
    Field("p", "grid", True, "float64", None, "trajectory", "grid momenta p_k (T*Q)"),
    Field("H", "grid", False, "float64", np.nan, "trajectory", "continuous Hamiltonian H(q_k, p_k)"),
    Field("Ed", "grid", False, "float64", np.nan, "trajectory",
          "discrete energy -D3 Ld of the trial full step from each grid state (not the step taken where "
          "impact_step is true)"),
    Field("Hmod", "grid", False, "float64", np.nan, "trajectory", "truncated modified Hamiltonian H~^{O(h^s)}",
          only="modified"),
    Field("impacts", "impact", False, "float64", None, "impacts", "impact times, ascending"),
    Field("impact_q", "impact", True, "float64", None, "impacts", "configuration at each impact"),
    Field("impact_p_minus", "impact", True, "float64", None, "impacts", "momentum before each impact"),
    Field("impact_p_plus", "impact", True, "float64", None, "impacts", "momentum after each impact"),
    Field("impact_impulse", "impact", False, "float64", None, "impacts",
          "impulse lambda of each contact impact: p+ = p- + sum over the impact's contacts of lambda_i grad phi_i(q)"),
    Field("impact_contact", "impact", False, "int64", None, "impacts",
          "index of the impact's constraint, in declaration order (simultaneous impacts: one entry each)"),
    Field("impact_step", "step", False, "bool", 0, "trajectory", "True where step k -> k+1 contained an impact"),
    Field("partial_steps", "partial", False, "float64", None, "impacts", "every partial step length Delta tau taken"),
    Field("newton_iters", "step", False, "int64", 0, "trajectory", "Newton iterations spent in step k -> k+1"),
    # held (resting) contacts
    Field("contact_active", "grid", False, "bool", 0, "trajectory", "True where contact i is held at t_k",
          contacts=True),
    Field("contact_force", "grid", False, "float64", 0.0, "trajectory",
          "multiplier of each held contact at t_k (its contact force along grad phi_i, >= 0; 0 when free)",
          contacts=True),
    Field("releases", "release", False, "float64", None, "impacts", "times at which a held contact is released"),
    Field("release_contact", "release", False, "int64", None, "impacts", "index of each released constraint"),
    # friction (docs/derivations/friction.md): zero, and no entries, for frictionless systems
    Field("impact_impulse_t", "impact", False, "float64", None, "impacts",
          "tangential (friction) impulse of each contact impact: p+ = p- + sum of lambda_i grad phi_i(q) + "
          "lambda_t,i W_t,i(q) (0 without friction)"),
    Field("contact_mode", "grid", False, "int8", 0, "trajectory",
          "mode of each contact at t_k: 0 free, +1 or -1 held and slipping (the sign of its slip velocity; "
          "frictionless held contacts are +1), 2 held and stuck", contacts=True),
    Field("friction_work", "step", False, "float64", 0.0, "trajectory",
          "work of the friction forces of held contacts over step k -> k+1 (<= 0)"),
    Field("mode_changes", "mode", False, "float64", None, "impacts",
          "times at which a held contact changes its friction mode (located events)"),
    Field("mode_change_contact", "mode", False, "int64", None, "impacts", "index of each such constraint"),
    Field("mode_change_kind", "mode", False, "int64", None, "impacts",
          "1 slip -> stick, 2 stick -> slip, 3 slip reversed (slip stopped, stick not possible)"),
)
FIELD = {f.name: f for f in FIELDS}

# The friction rows: at their fill values (zero; no entries) in every run of a frictionless system. A
# results file stores them only for a run where some differs (its attribute `friction_rows` says
# which; the readers give the others these values back), and the stored-size estimates count them only
# for systems with friction (vcirun.core.sizes.stored_bytes).
FRICTION_ROWS = ("impact_impulse_t", "contact_mode", "friction_work", "mode_changes", "mode_change_contact",
                 "mode_change_kind")

COUNTERS = ("status", "fail_step", "n_impacts", "n_partial", "steps", "n_releases", "n_mode_changes")

# the constraint switch, the tolerances of vcirun.core.tolerances.TOLERANCES (each once) and two flags,
# in the order of the generated modules' S_<NAME> constants
SETTINGS = ("constrained", "newton_tol", "max_iter", "event_tol", "max_impacts_step", "energies", "resting_contact")

# (name, meaning) in code order: the module's ST_<NAME> = code, Trajectory.status = name
STATUSES = (
    ("ok", "the run reached T"),
    ("newton_failed", "a full/partial step or reset solve did not converge"),
    ("event_failed", "the collision-time search did not converge"),
    ("reset_failed", "the reset map found no nontrivial root"),
    ("accumulation", "impacts denser than the grid for > max_impacts_step steps (or in one step)"),
    ("nonfinite", "a state became inf/NaN (or the initial energy is not finite)"),
    ("painleve", "a held contact slipping with friction has no unique normal force (Painleve's paradox)"),
)
STATUS_CODES = {code: name for code, (name, _) in enumerate(STATUSES)}
STATUS_OF = {name: code for code, name in STATUS_CODES.items()}


def module_constants() -> str:
    """The index and status constants of the record, as module source (vcirun.codegen.units emits
    them into every generated module): O_<FIELD>, I_<COUNTER>, S_<SETTING>, ST_<STATUS>."""
    lines = [f"{f.index_name} = {k}" for k, f in enumerate(FIELDS)]
    lines += [f"I_{c.upper()} = {k}" for k, c in enumerate(COUNTERS)]
    lines += [f"S_{s.upper()} = {k}" for k, s in enumerate(SETTINGS)]
    lines += [f"ST_{name.upper()} = {code}" for code, (name, _) in enumerate(STATUSES)]
    return "\n".join(lines)


def settings_vector(**values) -> np.ndarray:
    """The loop's settings array from keyword values (every SETTINGS name, nothing else)."""
    missing, extra = set(SETTINGS) - set(values), set(values) - set(SETTINGS)
    if missing or extra:
        raise ValueError(f"settings: missing {sorted(missing)}, unknown {sorted(extra)}")
    return np.array([float(values[s]) for s in SETTINGS], dtype=np.float64)


def impact_capacity(N: int) -> int:
    """Entries the impact record of an N-step run starts with (the loop grows it when it is full)."""
    return max(64, int(N) // 4 + 16)


def axis_rows(N: int, cap_impacts: int | None = None) -> dict:
    """{axis: rows} of the loop's buffers for an N-step run: N + 1 grid states, N steps, the impact
    record (`impact_capacity(N)` unless given), twice that plus 16 partial steps, releases and mode
    changes as impacts."""
    cap = impact_capacity(N) if cap_impacts is None else int(cap_impacts)
    return {"grid": int(N) + 1, "step": int(N), "impact": cap, "partial": 2 * cap + 16, "release": cap, "mode": cap}


def allocate(N: int, n: int, m: int = 1, cap_impacts: int | None = None) -> tuple:
    """The loop's output tuple, one buffer per FIELDS row in table order (m: constraints), sized by
    `axis_rows`."""
    rows = axis_rows(N, cap_impacts)
    out = []
    for f in FIELDS:
        shape = f.shape(rows[f.axis], n, m)
        dt = np.bool_ if f.dtype == "bool" else np.dtype(f.dtype)
        out.append(np.empty(shape, dt) if f.fill is None else np.full(shape, f.fill, dt))
    return tuple(out)


def trim(out: tuple, counters: dict, modified: bool) -> dict:
    """{name: array} of a finished loop: grid rows up to the last state reached, step rows up to the
    steps taken, impacts and partial steps up to their counts (copies where the buffer is larger)."""
    steps = counters["steps"]
    used = {"grid": steps + 1, "step": steps, "impact": counters["n_impacts"], "partial": counters["n_partial"],
            "release": counters["n_releases"], "mode": counters["n_mode_changes"]}
    arrays = {}
    for (name, axis, grid, only_modified), buf in zip(_TRIM, out):
        if only_modified and not modified:
            arrays[name] = None
            continue
        k = used[axis]
        arrays[name] = buf[:k] if grid else buf[:k].copy()
    return arrays


# (name, axis, a grid row, only with a modified energy) of each field: what `trim` reads per run
_TRIM = tuple((f.name, f.axis, f.axis == "grid", f.only == "modified") for f in FIELDS)


def stored_names(kind: str) -> tuple:
    """Names of the rows stored as `kind` ("impacts": always, "trajectory": with trajectories)."""
    return tuple(f.name for f in FIELDS if f.stored == kind)


def schema_markdown() -> str:
    """The per-run datasets table of docs/reference/results_schema.md (tests check the document holds it)."""
    hdf = {"float64": "f8", "int64": "i8", "int8": "i1", "bool": "u1"}
    lines = ["| dataset | shape, dtype | stored | meaning |", "|---|---|---|---|",
             "| `t` | (N+1,) f8 | with trajectories | grid times t0 + k h |"]
    size = {"grid": "N+1", "step": "N", "impact": "K_i", "partial": "K_p", "release": "K_r", "mode": "K_m"}
    when = {"impacts": "always", "trajectory": "with trajectories"}
    for f in FIELDS:
        if f.stored == "no":
            continue
        dims = [size[f.axis]] + (["n"] if f.dof else []) + (["m"] if f.contacts else [])
        shape = f"({', '.join(dims)})" if len(dims) > 1 else f"({dims[0]},)"
        note = " (MCVA family only)" if f.only == "modified" else \
            " (runs with friction only: see `friction_rows`)" if f.name in FRICTION_ROWS else ""
        lines.append(f"| `{f.name}` | {shape} {hdf[f.dtype]} | {when[f.stored]} | {f.doc}{note} |")
    return "\n".join(lines)
