"""A Trajectory as one HDF5 group (and the pieces to read it back): the attribute encoding (JSON attributes, NaN for absent
floats, clean UTF-8 text), the run record's rows as datasets, and the energy summary stored with each
run. `Trajectory.save(".h5")`, `read_trajectory` and the sweep's results files (vcirun.io.writer, vcirun.io.reader)
all write and read run groups through this module, so there is one codec and the Python API layer does
not import the experiment layer (tests/unit/test_layers.py).
"""
from __future__ import annotations

import functools
import json
import math
from typing import TYPE_CHECKING

import numpy as np

from ..core import record

if TYPE_CHECKING:  # h5py is imported by the callers that write files
    import h5py

# Attributes holding JSON text (decoded by the readers here; plain h5py users call json.loads).
JSON_ATTRS = {"tolerances", "options", "method_spec", "history", "config_canonical", "versions", "h_values",
              "methods", "ic_keys", "system_spec", "resolved_method", "constraints"}
# Per-step arrays dropped when store_trajectories is false; the impact record is always kept.
# the run record's rows (vcirun.core.record.FIELDS): per-step arrays with store_trajectories, the impact
# record always
TRAJECTORY_ARRAYS = ("t",) + record.stored_names("trajectory")
IMPACT_ARRAYS = record.stored_names("impacts")



# --- attribute encoding -----------------------------------------------------------------------------
def encode_attr(key, value):
    if key in JSON_ATTRS:
        return json.dumps(value, sort_keys=True, default=_json_default)
    if value is None:
        return np.nan if key in _FLOAT_ATTRS else ""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (list, tuple)):
        return np.asarray(value, dtype=float)
    if isinstance(value, str):
        return _clean_text(value)
    return value


def fixed_text(value: str) -> np.ndarray:
    """`value` as HDF5 stores vcirun's text: a 0-d array of h5py's fixed-length UTF-8 string type, as
    long as its UTF-8 bytes (at least 1). Fixed-length strings live in the object that holds them (an
    object header, or a dataset's data); variable-length ones live in the file's global heap, whose
    damaged collections libhdf5 can loop on without returning, so no file vcirun writes has any.
    h5py reads it back as bytes (`decode_attr`, `text_of` turn them into str)."""
    import h5py

    b = _clean_text(str(value)).encode("utf-8")
    return np.array(b, dtype=h5py.string_dtype("utf-8", max(1, len(b))))


def fixed_texts(values) -> np.ndarray:
    """A sequence of str as one array of h5py's fixed-length UTF-8 string type, as long as the longest
    (at least 1 byte; shorter ones padded with NUL, which h5py and numpy strip on reading)."""
    import h5py

    arr = np.asarray(values, dtype=object)
    enc = [_clean_text(str(v)).encode("utf-8") for v in arr.ravel()]
    n = max([1, *map(len, enc)])
    return np.array(enc, dtype=h5py.string_dtype("utf-8", n)).reshape(arr.shape)


def storable(value):
    """An encoded attribute value as vcirun writes it: text (str, bytes, arrays of them) as fixed-length
    strings (`fixed_text`), anything else unchanged."""
    if isinstance(value, (str, np.str_)):
        return fixed_text(value)
    if isinstance(value, (bytes, np.bytes_)):
        return np.array(bytes(value), dtype=f"S{max(1, len(value))}")
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, str) for v in value):
        return fixed_texts(value)
    if isinstance(value, np.ndarray) and (value.dtype.kind == "U" or (
            value.dtype == object and all(isinstance(v, str) for v in value.ravel()))):
        return fixed_texts(value)
    return value


def text_of(value) -> str:
    """A stored text value as str: fixed-length strings come back as bytes (UTF-8), variable-length
    ones (files written before every string was fixed-length) as str."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    if isinstance(value, (bytes, np.bytes_)):
        return bytes(value).decode("utf-8", "replace")
    return str(value)


def _clean_text(s: str) -> str:
    """Text HDF5 can store: no NUL (HDF5 strings end at one; fixed-length ones are padded with them) and
    valid UTF-8 (no lone surrogates)."""
    if "\x00" in s:
        s = s.replace("\x00", "\ufffd")
    try:
        s.encode("utf-8")
    except UnicodeEncodeError:
        s = s.encode("utf-8", "replace").decode("utf-8")
    return s


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def decode_attr(key, value):
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if key in JSON_ATTRS and isinstance(value, str):
        try:
            return json.loads(value)
        except ValueError:
            return None  # damaged (not JSON): absent rather than text where a mapping or list is expected
    if isinstance(value, np.ndarray):
        return value.tolist() if value.ndim else value.item()
    if isinstance(value, np.generic):
        return value.item()
    return value


_PLAIN = (float, int, bool)


def attr_items(attrs):
    """(name, value) pairs of an HDF5 object's attributes (an h5py AttributeManager), or of a mapping.
    The names are taken by index up to the count the object header records: h5py's own iteration
    walks the attribute index, which a damaged file can make cyclic (it then never ends, collecting
    names without bound)."""
    aid = getattr(attrs, "_id", None)
    if aid is None:
        return list(attrs.items())
    from h5py import h5, h5a

    order = h5.INDEX_CRT_ORDER if aid.get_create_plist().get_attr_creation_order() else h5.INDEX_NAME
    names = [h5a.open(aid, index=i, index_type=order).name.decode() for i in range(h5a.get_num_attrs(aid))]
    return [(k, attrs[k]) for k in names]


def decode_attrs(attrs) -> dict:
    # plain numbers are what they are (most of a run's ~45 attributes; a sweep's summary decodes all)
    return {k: v if type(v) in _PLAIN else decode_attr(k, v) for k, v in attr_items(attrs)}



# HDF5 library version bounds of the files written here: object headers of HDF5 1.8 or later, whose
# dense attribute storage holds an attribute of any size (a fixed-length text attribute is stored
# whole in its object; the 1.6 header format refuses one over 64 KiB)
LIBVER = ("v108", "latest")

_FLOAT_ATTRS = {"beta", "l2_error", "fail_time", "H0", "max_abs_dH", "H_range", "Ed_range", "Hmod_range",
                "accuracy", "rtol", "ref_h", "wall_time", "wall_time_call", "T", "T_requested", "h"}



# --- Trajectory <-> HDF5 -----------------------------------------------------------------------------
def _n_contacts(traj) -> int:
    """m, the number of constraints: the trailing axis of the per-contact rows (1 when none is recorded)."""
    ca = getattr(traj, "contact_active", None)
    return int(np.shape(ca)[1]) if ca is not None and np.ndim(ca) == 2 else 1


def thinned_rows(n_grid: int, every: int) -> np.ndarray:
    """The grid rows a run stores with `store: {every: k}`: 0, k, 2k, ... and the last."""
    rows = np.arange(0, n_grid, max(1, int(every)))
    return rows if n_grid == 0 or rows[-1] == n_grid - 1 else np.append(rows, n_grid - 1)


def trajectory_payload(traj, *, store_arrays: bool | int = True) -> tuple[dict, dict]:
    """(attrs, arrays) of a `vcirun.run.trajectory.Trajectory` for one run group. store_arrays: True
    (every grid state), False or 0 (the impact record and summaries only), or k >= 2: every k-th grid
    state and the last (the per-step rows, impact_step and newton_iters, are then left out)."""
    every = int(store_arrays) if not isinstance(store_arrays, bool) else int(store_arrays)
    attrs = {
        "core_method": traj.method, "system": traj.system, "h": float(traj.h), "T": float(traj.T),
        "status": traj.status, "message": " ".join(str(traj.message).split()),
        "fail_step": int(traj.fail_step), "fail_time": float(traj.fail_time),
        "beta": float("nan") if traj.beta is None else float(traj.beta),
        "wall_time": float(traj.wall_time), "n_steps": int(len(traj.t) - 1), "n_impacts": int(len(traj.impacts)),
        "n_partial_steps": int(len(traj.partial_steps)), "n_releases": int(len(traj.releases)),
        "n_mode_changes": int(len(traj.mode_changes)),
        "n_contacts": _n_contacts(traj),
        "newton_iters_total": int(np.sum(traj.newton_iters)) if len(traj.newton_iters) else 0,
        "has_Hmod": traj.Hmod is not None, "has_trajectory": every > 0, "store_every": every,
        "friction_rows": has_friction_data(traj),
        "tolerances": dict(traj.tolerances), "options": dict(traj.options),
        "tier": traj.tier or "", "build": traj.build or "",   # ("": not known, e.g. a run read from an old file)
    }
    attrs.update(energy_summary(traj))
    left_out = () if attrs["friction_rows"] else record.FRICTION_ROWS
    arrays = {name: getattr(traj, name) for name in IMPACT_ARRAYS if name not in left_out}
    rows = thinned_rows(len(traj.t), every) if every > 1 else None
    if every:
        for name in TRAJECTORY_ARRAYS:
            value = getattr(traj, name)
            if value is None or name in left_out:
                continue
            if rows is not None:
                if name in record.FIELD and record.FIELD[name].axis == "step":
                    continue
                value = np.asarray(value)[rows]
            if name in record.FIELD and record.FIELD[name].dtype == "bool":
                value = np.asarray(value, dtype=np.uint8)  # 0/1: portable, unlike HDF5's bool enum
            arrays[name] = value
    return attrs, {k: np.asarray(v) for k, v in arrays.items()}


def has_friction_data(traj) -> bool:
    """Whether some friction row of a run (vcirun.core.record.FRICTION_ROWS) differs from its fill value
    (zero, bit for bit: -0.0 differs; for the mode-change rows: any entry). Where none does, a results
    file leaves them out and `friction_fill` gives them back exactly; never true for a frictionless
    system."""
    for name in record.FRICTION_ROWS:
        a = getattr(traj, name, None)
        if a is None or not np.size(a):
            continue
        if record.FIELD[name].axis == "mode" or np.any(np.ascontiguousarray(a).view(np.uint8)):
            return True
    return False


def friction_fill(name: str, g, n_contacts: int | None = None) -> np.ndarray:
    """The fill value of friction row `name` for a run stored without its friction rows (attribute
    `friction_rows` false): zeros as long as the stored row on the same axis (contact_active for the
    grid, newton_iters for the steps, impacts; empty where that is not stored), no mode changes."""
    f = record.FIELD[name]
    dt = np.dtype(f.dtype)
    like = {"grid": "contact_active", "step": "newton_iters", "impact": "impacts"}.get(f.axis)
    if like is None or like not in g:
        return np.zeros(f.shape(0, 0, 0 if n_contacts is None else n_contacts), dt)
    shape = tuple(np.shape(g[like]))
    if f.contacts and len(shape) < 2:
        shape = (shape[0], 0 if n_contacts is None else n_contacts)
    return np.zeros(shape[:1] + (shape[1:2] if f.contacts else ()), dt)


def group_attrs(attrs: dict) -> dict:
    """The attributes of a run/reference group as stored (encoded; `complete` excluded)."""
    return {key: encode_attr(key, value) for key, value in attrs.items()
            if key != "complete" and not (value is None and key not in _FLOAT_ATTRS)}
    # (None is absent rather than a placeholder; float attributes use NaN)


def write_encoded(f: "h5py.File", path: str, enc_attrs: dict, arrays, group=None) -> None:
    """Write one group from encoded attributes and (name, array) pairs (into `group`, an open group at
    `path` that already holds other datasets, when given); `complete` goes last. (No flush
    per group: groups are only ever written into a copy that replaces the file once it is complete,
    and a flush per group made a 2000-run compaction 20x slower.)

    The objects are made with h5py's low-level calls, with the types, dataspaces and creation
    properties of its high-level `create_dataset(name, data=a)` and `attrs[key] = value` (readers see
    the same file), without their per-call Python: a sweep writes ~17 datasets and ~45 attributes
    per run, which the high-level calls make 2.4x slower (tests/unit/test_storage.py compares both)."""
    import h5py

    if group is not None:
        gid = group.id
    else:
        if path in f:
            del f[path]
        parent, _, name = path.rpartition("/")
        gid = h5py.h5g.create((f.require_group(parent) if parent else f).id, name.encode())
    h5 = _H5()
    for dname, value in arrays:
        a = np.asarray(value, order="C")  # (ascontiguousarray would make a 0-d array 1-d)
        d = h5py.h5d.create(gid, dname.encode(), h5.types(a.dtype)[0], h5py.h5s.create_simple(a.shape),
                            dcpl=h5.dcpl)
        d.write(h5py.h5s.ALL, h5py.h5s.ALL, a)
    for key, value in enc_attrs.items():
        _write_attr(gid, key, value, h5)
    _write_attr(gid, "complete", True, h5)


def _write_attr(gid, key: str, value, h5) -> None:
    import h5py

    if isinstance(value, (str, bytes)):
        a = storable(value)
        htype = mtype = h5py.h5t.py_create(a.dtype, logical=True)
    elif isinstance(value, (bool, int, float, np.ndarray, np.generic)) and np.asarray(value).dtype.kind in "biuf":
        a = np.asarray(value, order="C")
        htype, mtype = h5.types(a.dtype)
    else:  # anything else (arrays of text, ...): h5py's own conversion
        h5py.AttributeManager(_Parent(gid))[key] = storable(value)
        return
    name = key.encode()
    if h5py.h5a.exists(gid, name):
        h5py.h5a.delete(gid, name)
    h5py.h5a.create(gid, name, htype, h5py.h5s.create_simple(a.shape)).write(a, mtype=mtype)


class _Parent:
    """What h5py.AttributeManager needs of the object it belongs to: its identifier."""

    def __init__(self, gid):
        self.id = gid


@functools.lru_cache(maxsize=1)
def _H5():
    return _H5Types()


class _H5Types:
    """h5py's types for numpy dtypes (file type: logical, memory type: bit-level, as its high-level
    calls make them) and its default dataset creation properties (no filters, no modification
    times), made once."""

    def __init__(self):
        import h5py

        self._types = {}
        self.dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
        self.dcpl.set_obj_track_times(False)

    def types(self, dtype):
        t = self._types.get(dtype.str)
        if t is None:
            import h5py

            t = self._types[dtype.str] = (h5py.h5t.py_create(dtype, logical=True), h5py.h5t.py_create(dtype))
        return t


def write_group(f: "h5py.File", path: str, attrs: dict, arrays: dict) -> None:
    """Write one run/reference group from a payload (attributes as `trajectory_payload` gives them)."""
    write_encoded(f, path, group_attrs(attrs), arrays.items())


# --- energy summary of a run ---------------------------------------------------------------------------
def masked_discrete_energy(traj) -> np.ndarray:
    """-D3 Ld per grid point, NaN where the step from that point contained an impact (there the
    recorded value belongs to the rejected trial step, not to the step taken)."""
    Ed = np.array(traj.Ed, dtype=float, copy=True)
    imp = np.asarray(traj.impact_step, bool)
    k = min(len(imp), len(Ed))
    Ed[:k][imp[:k]] = np.nan
    return Ed


def _finite_range(x) -> float:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(x.max() - x.min()) if x.size else math.nan


def energy_summary(traj) -> dict:
    """H0, max |H - H0|, and the ranges (max - min over the run) of H, of -D3 Ld with impact steps
    masked, and of the truncated modified Hamiltonian (NaN where not defined)."""
    H = np.asarray(traj.H, float)
    H0 = float(H[0]) if H.size else math.nan
    return {
        "H0": H0,
        "max_abs_dH": float(np.nanmax(np.abs(H - H0))) if H.size and np.isfinite(H0) else math.nan,
        "H_range": _finite_range(H),
        "Ed_range": _finite_range(masked_discrete_energy(traj)) if len(traj.Ed) else math.nan,
        "Hmod_range": _finite_range(traj.Hmod) if traj.Hmod is not None else math.nan,
    }
