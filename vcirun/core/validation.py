"""Input bounds shared by the Python API, the config layer and the system loader (issue 22).

Everything here runs before work starts and turns bad input into a one-line `ValueError` that names
the field and says what to write instead, in the phrasing of the config layer
(``h: must be > 0 (got 0)``):

- argument checks of `vcirun.simulate` and `vcirun.reference` (numbers, tolerances, initial state);
- the grid size and the memory of a run, estimated from T / h, n and the stored fields, refused above
  a configurable limit (`max_memory` in a sweep config, the VCIRUN_MAX_MEMORY environment variable, or
  `set_memory_limit`) before anything is allocated or created;
- identifiers (parameters, coordinates, system names): ASCII after NFKC normalisation and no two that
  collide after it (Python normalises identifiers with NFKC, so the generated kernels would read
  ``s_ｋ`` as ``s_k``);
- YAML text (configs and system files alike): YAML 1.2 numbers (``1e-3`` is a float), duplicate keys
  rejected, aliases expanded under a size cap (a billion-laughs document is refused in milliseconds,
  before anything walks or prints it), a cap on the text itself.

No sympy and no numba here: `experiments/` imports this module.
"""
from __future__ import annotations

import contextlib
import contextvars
import keyword
import math
import numbers
import os
import re
import reprlib
import unicodedata

import numpy as np
import yaml

__all__ = ["MAX_STEPS", "MIN_H", "MAX_YAML_CHARS", "MAX_YAML_NODES", "MAX_COORDINATES", "MAX_PARAMETERS",
           "check_number", "check_simulate_args", "check_scene_size", "check_reference_args", "check_state_vector", "grid_size",
           "run_bytes", "stored_bytes", "memory_limit", "set_memory_limit", "limit_memory", "parse_bytes", "format_bytes",
           "check_run_memory", "check_identifier", "check_distinct_names", "ascii_name_problem", "reserved_name_problem",
           "yaml_load", "YAMLLimitError", "nonfinite_start", "describe"]

# Grid: N = round(T / h) steps. Beyond 1e12 nothing fits in memory anyway (and T / h stops being an
# exact integer count near 2**53); below 1e-50 the h**k terms of the discrete Lagrangians and of the
# modified Hamiltonians (k <= 6) leave the normal floating-point range.
MAX_STEPS = 1e12
MIN_H = 1e-50
# YAML: a config or system file is a few kB; 4 MB of text or a million expanded nodes is hostile.
MAX_YAML_CHARS = 4_000_000
MAX_YAML_NODES = 1_000_000
MAX_YAML_SCALAR_CHARS = 20_000_000  # characters of every scalar after alias expansion
# Declarations of user systems (the generated kernels grow like n**2 to n**4).
MAX_COORDINATES = 32
MAX_PARAMETERS = 1024
MAX_NAME_CHARS = 64

_repr = reprlib.Repr()
_repr.maxstring = 40
_repr.maxother = 40
_repr.maxlist = _repr.maxtuple = _repr.maxdict = 4
_repr.maxlevel = 2


def describe(value) -> str:
    """A short repr, bounded whatever the value (never builds the repr of a huge structure)."""
    try:
        s = _repr.repr(value)
    except Exception:  # noqa: BLE001 - a hostile __repr__
        s = f"<{type(value).__name__}>"
    return s if len(s) <= 60 else s[:57] + "..."


# --- numbers --------------------------------------------------------------------------------------
def _as_real(value):
    """float of a real scalar (Python or numpy number, 0-d array), else None. bool is not a number."""
    if isinstance(value, (bool, np.bool_)):
        return None
    if isinstance(value, np.ndarray):
        if value.ndim != 0 or value.dtype.kind not in "iuf":
            return None
        value = value[()]
    if isinstance(value, numbers.Real):
        try:
            return float(value)
        except (OverflowError, ValueError, TypeError):
            return math.inf if value > 0 else -math.inf
    return None


def check_number(field: str, value, *, gt=None, ge=None, lt=None, le=None, integer: bool = False):
    """`value` as a float (or int with `integer`) within the bounds; ValueError '<field>: must be ...'."""
    x = _as_real(value)
    if integer:
        if x is None or not math.isfinite(x) or x != math.floor(x):
            raise ValueError(f"{field}: must be an integer (got {describe(value)})")
        x = int(x)
    elif x is None or not math.isfinite(x):
        raise ValueError(f"{field}: must be a finite number (got {describe(value)})")
    for bound, ok, op in ((gt, lambda b: x > b, ">"), (ge, lambda b: x >= b, ">="), (lt, lambda b: x < b, "<"),
                          (le, lambda b: x <= b, "<=")):
        if bound is not None and not ok(bound):
            raise ValueError(f"{field}: must be {op} {bound:g} (got {describe(value)})")
    return x


def check_bool(field: str, value, *, allow_none: bool = False):
    if value is None and allow_none:
        return None
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise ValueError(f"{field}: must be true or false (got {describe(value)})")


def check_state_vector(field: str, value, n: int | None = None) -> np.ndarray:
    """A flat vector of finite numbers (a scalar counts as length 1)."""
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise ValueError(f"{field}: must be a list of finite numbers (got {describe(value)})")
    try:
        a = np.asarray(value)
    except Exception:  # noqa: BLE001 - ragged lists and odd objects
        raise ValueError(f"{field}: must be a list of finite numbers (got {describe(value)})") from None
    if a.dtype.kind == "b" or a.dtype.kind not in "iuf" or a.ndim > 1:
        raise ValueError(f"{field}: must be a flat list of finite numbers (got {describe(value)})")
    a = a.astype(float).ravel()
    if a.size == 0 or not np.all(np.isfinite(a)):
        raise ValueError(f"{field}: must be a list of finite numbers (got {describe(value)})")
    if n is not None and a.size != n:
        raise ValueError(f"{field}: must have length {n} (got {a.size})")
    return a


# --- grid and memory ----------------------------------------------------------------------------------
def grid_size(h, T, *, h_field: str = "h", T_field: str = "T") -> int:
    """N = round(T / h) for validated h and T (> 0, finite, h >= MIN_H, 1 <= N <= MAX_STEPS)."""
    h = check_number(h_field, h, gt=0)
    T = check_number(T_field, T, gt=0)
    if h < MIN_H:
        raise ValueError(f"{h_field}: must be >= {MIN_H:g} (got {h:g}); smaller steps underflow the h**k terms "
                         "of the discrete Lagrangians")
    steps = T / h
    if not steps <= MAX_STEPS:
        raise ValueError(f"{h_field}: T / h = {steps:.3g} steps is too many (at most {MAX_STEPS:.0e}); "
                         "raise h or lower T")
    N = int(round(steps))
    if N < 1:
        raise ValueError(f"{T_field}: must be at least one step h (got T={T:g}, h={h:g})")
    return N


def run_bytes(N: int, n: int, m: int = 1) -> int:
    """Bytes `vcirun.simulate` allocates for an N-step run of n coordinates and m constraints: one
    buffer per row of the run record (vcirun.core.record.FIELDS, sized as api._run sizes them: impacts
    N/4 + 16, partial steps twice that, releases as impacts) and the time grid."""
    from . import record  # (foundation layer: numpy only)

    N, n, m = int(N), int(n), int(m)
    cap = max(64, N // 4 + 16)
    rows = {"grid": N + 1, "step": N, "impact": cap, "partial": 2 * cap + 16, "release": cap}
    b = 0
    for f in record.FIELDS:
        size = math.prod(f.shape(rows[f.axis], n, m))   # (math.prod: np.prod costs ~5 us a call, 18 per run)
        b += size * (1 if f.dtype == "bool" else np.dtype(f.dtype).itemsize)
    return b + 16 * (N + 1) + 128  # t and its integer arange


def stored_bytes(N: int, n: int, *, store_trajectories: bool = True, impacts: int = 0) -> int:
    """Bytes of one run's datasets in the results file (and of its result message to the client)."""
    N, n = int(N), int(n)
    b = impacts * (8 * (1 + 3 * n) + 16) + 4096  # impact record, attributes and group overhead
    if store_trajectories:
        b += (N + 1) * 8 * (2 * n + 4) + N * 9  # t, q, p, H, Ed, Hmod; impact_step, newton_iters
    return b


_UNITS = {"": 1, "b": 1, "k": 1e3, "kb": 1e3, "m": 1e6, "mb": 1e6, "g": 1e9, "gb": 1e9, "t": 1e12, "tb": 1e12,
          "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}


def parse_bytes(value, field: str = "max_memory") -> int:
    """A byte count from a number or text such as '8 GB', '512MiB' (ValueError naming the field)."""
    x = _as_real(value)
    if x is None and isinstance(value, str):
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([A-Za-z]*)\s*", value)
        if m and m.group(2).lower() in _UNITS:
            x = float(m.group(1)) * _UNITS[m.group(2).lower()]
    if x is None or not math.isfinite(x) or x <= 0:
        raise ValueError(f"{field}: must be a positive size such as 8GB, 512MiB or a number of bytes "
                         f"(got {describe(value)})")
    return int(x)


def format_bytes(b: float) -> str:
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if b >= size:
            v = b / size
            return f"{v:.3g} {unit}" if v < 1000 else f"{v:.0f} {unit}"
    return f"{int(b)} B"


_LIMIT: int | None = None
# a sweep's max_memory, for the runs it computes in this thread (see `limit_memory`)
_SCOPED: contextvars.ContextVar = contextvars.ContextVar("vcirun_memory_limit", default=None)


def _physical_memory() -> int:
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return 8 * 2**30


def memory_limit() -> int:
    """Bytes one run (or a sweep's runs in flight) may take: `set_memory_limit`, else VCIRUN_MAX_MEMORY,
    else half of the physical memory."""
    if _SCOPED.get() is not None:
        return _SCOPED.get()
    if _LIMIT is not None:
        return _LIMIT
    env = os.environ.get("VCIRUN_MAX_MEMORY")
    if env:
        return parse_bytes(env, "VCIRUN_MAX_MEMORY")
    return _physical_memory() // 2


def set_memory_limit(limit) -> None:
    """Set the process-wide limit (bytes or text like '16GB'); None restores the default."""
    global _LIMIT
    _LIMIT = None if limit is None else parse_bytes(limit)


@contextlib.contextmanager
def limit_memory(limit):
    """The limit for the calls inside this block (this thread only); None: no change."""
    if limit is None:
        yield
        return
    token = _SCOPED.set(parse_bytes(limit))
    try:
        yield
    finally:
        _SCOPED.reset(token)


def check_run_memory(N: int, n: int, *, copies: int = 1, extra: int = 0, limit=None, field: str = "T",
                     hint: str = "") -> int:
    """Refuse a run whose buffers (times `copies` runs at once, plus `extra` bytes) exceed the limit."""
    need = copies * run_bytes(N, n) + int(extra)
    lim = memory_limit() if limit is None else parse_bytes(limit)
    if need > lim:
        who = f"{copies} runs at once" if copies > 1 else "one run"
        raise ValueError(f"{field}: {N:.4g} steps of {n} coordinates need about {format_bytes(need)} for {who} "
                         f"(limit {format_bytes(lim)}); raise h or lower T"
                         + (hint or ", or raise the limit (VCIRUN_MAX_MEMORY=32GB, or max_memory in a sweep config)"))
    return need


# --- the API's arguments ---------------------------------------------------------------------------------
_TOLERANCE_BOUNDS = {"newton_tol": dict(gt=0), "event_tol": dict(gt=0),
                     "max_iter": dict(ge=1, le=10_000, integer=True),
                     "max_impacts_step": dict(ge=1, le=100_000, integer=True)}


def check_params(params, field: str = "params") -> dict | None:
    if params is None:
        return None
    if not isinstance(params, dict):
        raise ValueError(f"{field}: must be a mapping of parameter names to numbers (got {describe(params)})")
    out = {}
    for k, v in params.items():
        if not isinstance(k, str):
            raise ValueError(f"{field}: names must be strings (got {describe(k)})")
        problem = ascii_name_problem(k)
        if problem:
            raise ValueError(f"{field}.{describe(k)}: {problem}")
        out[k] = check_number(f"{field}.{k}", v)
    return out


def check_system_names(system) -> None:
    """A MechanicalSystem built in Python: its coordinate and parameter names obey the loader's rules."""
    q = getattr(system, "q", None)
    params = getattr(system, "params", None)
    if not isinstance(q, (list, tuple)) or not isinstance(params, dict):
        return
    names = {f"coordinates[{i}]": getattr(s, "name", str(s)) for i, s in enumerate(q)}
    names.update({f"parameters.{k}": k for k in params})
    check_distinct_names(names, "system")
    for fld, name in names.items():
        problem = reserved_name_problem(name)
        if problem:
            raise ValueError(f"system.{fld}: {problem}")


def check_scene_size(system, field: str = "system") -> None:
    """A sized built-in scene (`n_pendulum_K`, `newton_cradle_K`) within the coordinate cap: its symbolic
    model and kernels grow like K**2 to K**4, and K = 100000 would build them until memory runs out."""
    if not isinstance(system, str):
        return
    m = re.fullmatch(r"([a-z_]+?)_(\d+)", system)
    if m and m.group(1) in ("n_pendulum", "newton_cradle"):
        k = int(m.group(2))
        if not 1 <= k <= MAX_COORDINATES:
            raise ValueError(f"{field}: {system} has {k} bodies; the built-in sized scenes take 1 to "
                             f"{MAX_COORDINATES}")


def check_one_start(beta, q0, p0) -> None:
    """Either beta or q0/p0: given both, one of them would be silently ignored (q0/p0 won)."""
    if beta is not None and (q0 is not None or p0 is not None):
        raise ValueError("beta: give either beta or q0 and p0, not both (the initial state would ignore one)")


def check_simulate_args(*, h, T, t0=0.0, beta=None, q0=None, p0=None, params=None, constrained=None,
                        energies=True, tolerances: dict | None = None, system=None, resting_contact=True) -> int:
    """Validate `vcirun.simulate`'s arguments (same bounds and messages as a sweep config); returns N."""
    N = grid_size(h, T)
    t0 = check_number("t0", t0)
    h = float(h)
    if not math.isfinite(t0 + float(T)) or t0 + h == t0:
        raise ValueError(f"t0: h = {h:g} is below the resolution of times near t0 = {t0:g}; use a smaller |t0|")
    check_one_start(beta, q0, p0)
    check_bool("resting_contact", resting_contact)
    if beta is not None:
        check_number("beta", beta)
    if q0 is not None:
        check_state_vector("q0", q0)
    if p0 is not None:
        check_state_vector("p0", p0)
    check_params(params)
    check_bool("constrained", constrained, allow_none=True)
    check_bool("energies", energies)
    for k, v in (tolerances or {}).items():
        if k in _TOLERANCE_BOUNDS:
            check_number(k, v, **_TOLERANCE_BOUNDS[k])
    if system is not None:
        check_scene_size(system)
        check_system_names(system)
    return N


def check_reference_args(*, T, rtol=1e-13, method="exact", h=None, beta=None, q0=None, p0=None,
                         params=None, system=None, resting_contact=True, check_accuracy=True) -> None:
    """Validate `vcirun.reference`'s arguments (the config layer's bounds on reference.rtol, T, h)."""
    check_number("T", T, gt=0)
    check_one_start(beta, q0, p0)
    check_bool("resting_contact", resting_contact)
    check_bool("check_accuracy", check_accuracy)
    check_scene_size(system)
    if not isinstance(method, str):
        raise ValueError(f"method: must be 'exact' or a method name (got {describe(method)})")
    if method == "exact":
        check_number("rtol", rtol, ge=2.3e-14, lt=1e-3)
    elif h is not None:
        grid_size(h, T)
    if beta is not None:
        check_number("beta", beta)
    if q0 is not None:
        check_state_vector("q0", q0)
    if p0 is not None:
        check_state_vector("p0", p0)
    check_params(params)


def nonfinite_start(H0, Ed0=0.0, Hmod0=0.0, q0=None, p0=None) -> str:
    """Why a run cannot be trusted from its first grid point ('' if it can): a non-finite initial energy
    (an initial state so large that H overflows) makes every energy error NaN."""
    bad = [(name, v) for name, v in (("H", H0), ("Ed", Ed0), ("Hmod", Hmod0)) if v is not None and not np.isfinite(v)]
    if not bad:
        return ""
    scale = ""
    if q0 is not None and p0 is not None:
        scale = f" (max |q0| = {float(np.max(np.abs(q0))):.3g}, max |p0| = {float(np.max(np.abs(p0))):.3g})"
    what = ", ".join(f"{k}(0) = {v}" for k, v in bad)
    return (f"non-finite initial energy: {what}; the initial state{scale} overflows the energy in floating "
            "point, so no energy or trajectory error can be measured")


# --- identifiers --------------------------------------------------------------------------------------------
def ascii_name_problem(name: str) -> str | None:
    """Why `name` is not an acceptable identifier, or None. Python reads identifiers through NFKC
    (so 'ｋ' is 'k' to generated code): names must be ASCII."""
    if not isinstance(name, str) or not name:
        return "must be a non-empty name"
    if len(name) > MAX_NAME_CHARS:
        return f"name is {len(name)} characters long; the limit is {MAX_NAME_CHARS}"
    if not name.isascii():
        norm = unicodedata.normalize("NFKC", name)
        bad = next(c for c in name if not c.isascii())
        what = f"{bad!r} (U+{ord(bad):04X} {unicodedata.name(bad, 'unnamed character')})"
        if norm.isascii() and norm.isidentifier():
            return (f"{describe(name)} is not ASCII: {what} reads as {norm!r} after Unicode normalisation (NFKC); "
                    f"write {norm!r}")
        return f"{describe(name)} is not ASCII: {what}; use ASCII letters, digits and '_'"
    return None


# Names the generated code gives its own symbols (vcirun.discrete slot symbols qa0.., va0.., qb0.., hh,
# tt; vcirun.codegen.tensor placeholders vcTQ0.., vcTV0.., vcTT, temporaries vcTC0.., outputs vcTG0..;
# CSE temporaries cse0..; vcirun.modified symbols mh_*; MechanicalSystem's numeric helpers xm0..). A
# coordinate or parameter with such a name is the same sympy Symbol or the same printed name as the
# generated one, so the kernels silently read the wrong value: a parameter named vcTQ0 is read as the
# first coordinate by the tensor kernels (status ok, a wrong trajectory).
_RESERVED_NAME = re.compile(r"hh|tt|(?:qa|va|qb|cse|xm)\d+|vcT\w*|mh_\w*")


def reserved_name_problem(name) -> str | None:
    """Why `name` cannot name a coordinate or parameter because generated code uses it, or None."""
    if isinstance(name, str) and _RESERVED_NAME.fullmatch(name):
        return (f"{name!r} is reserved: the generated kernels use it for their own symbols (reserved: hh, tt, "
                "qa<k>, va<k>, qb<k>, cse<k>, xm<k>, vcT..., mh_...); choose another name")
    return None


def check_identifier(name, field: str, *, reserved=()) -> str:
    """An ASCII Python identifier, not a keyword, not starting with '_', not reserved."""
    if not isinstance(name, str):
        raise ValueError(f"{field}: must be a name (got {describe(name)})")
    problem = ascii_name_problem(name)
    if problem:
        raise ValueError(f"{field}: {problem}")
    if not name.isidentifier() or name.startswith("_"):
        raise ValueError(f"{field}: {name!r} is not a valid name (letters, digits and '_', starting with a letter)")
    if keyword.iskeyword(name):
        raise ValueError(f"{field}: {name!r} is a Python keyword; choose another name")
    if name in reserved:
        raise ValueError(f"{field}: {name!r} is reserved; choose another name")
    problem = reserved_name_problem(name)
    if problem:
        raise ValueError(f"{field}: {problem}")
    return name


def check_distinct_names(names: dict, prefix: str) -> None:
    """No two names (field -> name) equal after NFKC; each name ASCII (collisions reported first)."""
    seen: dict[str, str] = {}
    for fld, name in names.items():
        key = unicodedata.normalize("NFKC", name) if isinstance(name, str) else name
        if key in seen:
            other = seen[key]
            how = "" if names[other] == name else " after Unicode normalisation (NFKC)"
            raise ValueError(f"{prefix}.{fld}: {describe(name)} collides with {prefix}.{other} "
                             f"({describe(names[other])}){how}; names must be distinct")
        seen[key] = fld
    for fld, name in names.items():
        problem = ascii_name_problem(name)
        if problem:
            raise ValueError(f"{prefix}.{fld}: {problem}")


# --- YAML --------------------------------------------------------------------------------------------------------
class YAMLLimitError(yaml.YAMLError):
    """A YAML document over the size caps (text, expanded nodes or characters)."""

    def __init__(self, problem: str, mark=None):
        self.problem = problem
        self.problem_mark = mark
        super().__init__(problem)


class SafeLoader(yaml.SafeLoader):
    """SafeLoader that reads 1e-2 as a float (YAML 1.2; YAML 1.1 wants 1.0e-2), rejects duplicate keys
    and refuses documents whose aliases expand past MAX_YAML_NODES nodes or MAX_YAML_SCALAR_CHARS
    characters (checked on the node graph, before any Python object is built)."""

    def get_single_data(self):
        node = self.get_single_node()
        if node is None:
            return None
        _check_expansion(node)
        return self.construct_document(node)


SafeLoader.yaml_implicit_resolvers = {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}
SafeLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                   |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                   |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                   |[-+]?\.(?:inf|Inf|INF)
                   |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."))


def _construct_mapping(loader, node, deep=False):
    loader.flatten_mapping(node)
    seen = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(None, None, f"a mapping key must be a plain value (got "
                                                    f"{describe(key)})", key_node.start_mark) from None
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {describe(key)} (first at line {seen[key] + 1})", key_node.start_mark)
        seen[key] = key_node.start_mark.line
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


SafeLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _check_expansion(root) -> None:
    """Expanded size of the node graph (aliases share nodes: memoised per node, so the count itself costs
    one visit per distinct node), refused above the caps. Iterative: deep nesting cannot recurse."""
    memo: dict[int, tuple[int, int]] = {}
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if key in memo and not done:
            continue
        children = []
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [c for pair in node.value for c in pair]
        if not done:
            memo[key] = (-1, -1)  # in progress: a child that meets it is an alias of its own ancestor
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in memo)
            continue
        count, chars = 1, len(node.value) if isinstance(node, yaml.ScalarNode) else 0
        for c in children:
            cc, ch = memo.get(id(c), (1, 0))
            if cc < 0:
                raise YAMLLimitError("recursive alias (a value that contains itself); write the values out",
                                     c.start_mark)
            count += cc
            chars += ch
        if count > MAX_YAML_NODES or chars > MAX_YAML_SCALAR_CHARS:
            raise YAMLLimitError(
                f"the document expands to more than {MAX_YAML_NODES:,} values or {MAX_YAML_SCALAR_CHARS:,} "
                "characters (YAML aliases repeat what they point to: an alias bomb?); write the values out",
                node.start_mark)
        memo[key] = (count, chars)


MAX_YAML_DEPTH = 100  # nesting of flow collections (PyYAML takes seconds to refuse 1000 levels)


def _flow_depth(text: str) -> int:
    """Deepest nesting of [ ] and { } outside quoted scalars (a scan before PyYAML recurses into it)."""
    depth = top = 0
    quote = None
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if quote:
            if c == "\\" and quote == '"':
                i += 1
            elif c == quote:
                quote = None
        elif c in "'\"":
            quote = c
        elif c == "#" and (i == 0 or text[i - 1] in " \t\n"):
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        elif c in "[{":
            depth += 1
            top = max(top, depth)
        elif c in "]}":
            depth -= 1
        i += 1
    return top


def yaml_load(text: str):
    """Parse YAML text of a config or a system file (see `SafeLoader`); YAMLError on bad input."""
    if not isinstance(text, str):
        raise YAMLLimitError(f"expected YAML text (got {type(text).__name__})")
    if len(text) > MAX_YAML_CHARS:
        raise YAMLLimitError(f"the text is {len(text):,} characters long; the limit is {MAX_YAML_CHARS:,}")
    if text.count("[") + text.count("{") > MAX_YAML_DEPTH and _flow_depth(text) > MAX_YAML_DEPTH:
        raise YAMLLimitError(f"the document nests [ ] or {{ }} more than {MAX_YAML_DEPTH} levels deep")
    loader = SafeLoader(text)
    try:
        return loader.get_single_data()
    except RecursionError:
        raise YAMLLimitError("the document is nested too deeply") from None
    finally:
        loader.dispose()
