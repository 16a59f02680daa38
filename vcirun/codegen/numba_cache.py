"""numba's compiled code for the kernel cache's modules: kept in the cache, checked, healed, announced.

numba caches a function's machine code next to its source (`kernels/__pycache__/<module>.<fn>-<line>.
py311.nbi` index and `.<n>.nbc` data), or under $NUMBA_CACHE_DIR, or, when that directory is not
writable, in ~/.cache/numba. For the modules of vcirun's kernel cache (`claim`), this module makes it
always `kernels/__pycache__`, whatever NUMBA_CACHE_DIR says and whether or not it is writable (a
read-only cache is loaded, not recompiled elsewhere), and replaces numba's file format by a checked
one:

- each file starts with a line `vcirun-numba 1 <sha256>`, the digest of the file's name and the
  payload (numba's own bytes), written atomically with fsync (vcirun.codegen.cache_store);
- a load verifies the line first: a zero-length, truncated, edited, renamed or unreadable file is
  moved to the quarantine and the function is compiled again, said on one line; a payload numba
  cannot unpickle or rebuild is treated the same way;
- a compile that follows a missing or set-aside file is announced once per module ("compiling ...");
- a save that fails (read-only cache, full disk) leaves the compiled code in memory for this process
  and says so once.
"""
from __future__ import annotations

import inspect
import io
import os
import pickle
import sys
from pathlib import Path

from numba.core import caching

from . import cache_store

MAGIC = b"vcirun-numba 1 "


class Owner:
    """What a claimed module is, for the lines this module says: `label` ("kernels for cart_pendulum/
    MCVA[SVC,s=4]", "the shared core of CVA[SVC]"), `estimate()` (seconds a compile takes, or None) and
    `on_event(kind, detail)` ("compiled" with the function numba compiles for want of cached code,
    "unsaved" with why its code could not be saved: the kernel cache's build reports)."""

    def __init__(self, label: str, estimate=None, on_event=None):
        self.label, self.estimate, self.on_event = label, estimate, on_event
        self.announced = False

    def compiling(self, fn: str) -> None:
        if self.on_event is not None:
            self.on_event("compiled", fn)
        if self.announced:
            return
        self.announced = True
        about = ""
        if self.estimate is not None:
            try:
                s = self.estimate()
                about = "" if s is None else f", about {float(s):.0f} s"
            except Exception:  # noqa: BLE001 - an estimate never stops a run
                about = ""
        # (a damaged file was said by its quarantine line, which counts as this announcement)
        cache_store.say(f"compiling {self.label}: {fn} is not compiled yet for this vcirun on this machine{about} "
                        f"(cached in {cache_store.root()})")

    def unsaved(self, where: str, e: Exception) -> None:
        text = " ".join(str(e).split())
        if self.on_event is not None:
            self.on_event("unsaved", text)
        cache_store.say(f"kernel cache: cannot save the compiled code of {self.label} in {where} ({text}); this "
                        f"process runs it from memory, the next one compiles it again", once=f"unsaved|{where}")


_CLAIMED: dict[str, Owner] = {}


def claim(path: Path, owner: Owner) -> None:
    """numba's files of the module at `path` go through this module (before the module is executed). A
    file where their directory should be is set aside, so that they can be saved again."""
    _CLAIMED[os.path.abspath(path)] = owner
    d = Path(os.path.abspath(path)).parent / "__pycache__"
    if os.path.lexists(d) and not d.is_dir():
        cache_store.quarantine(d, "is not a directory", rebuild="numba's files are saved in a new one")


def owner_of(path) -> Owner | None:
    return _CLAIMED.get(os.path.abspath(path))


class _Locator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
    """A claimed module's numba files: kernels/__pycache__ beside it, writable or not."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = os.path.join(os.path.dirname(os.path.abspath(py_file)), "__pycache__")

    def get_cache_path(self):
        return self._cache_path

    def ensure_cache_path(self):   # before a save only: its failure is the save's
        os.makedirs(self._cache_path, exist_ok=True)

    @classmethod
    def from_function(cls, py_func, py_file):
        if os.path.abspath(py_file) not in _CLAIMED:
            return None
        return cls(py_func, py_file)


if _Locator not in caching.CacheImpl._locator_classes:
    caching.CacheImpl._locator_classes.insert(0, _Locator)


class _Impl(caching.CompileResultCacheImpl):
    """numba's compile-result cache with the claimed locator (also when NUMBA_CACHE_LOCATOR_CLASSES
    names others)."""

    def __init__(self, py_func):
        self._lineno = py_func.__code__.co_firstlineno
        qualname = getattr(py_func, "__qualname__", py_func.__name__)
        source = inspect.getfile(py_func)
        self._locator = _Locator(py_func, source)
        modname = os.path.splitext(os.path.basename(source))[0]
        self._filename_base = self.get_filename_base(f"{modname}.{qualname}", getattr(sys, "abiflags", ""))


def index_exists(path: Path, fn: str, text: str) -> bool:
    """Has numba's cache an index for the top-level function `fn` of the claimed module file `path`, whose
    text is `text`? Its name is `_Impl`'s: `__pycache__/<module>.<fn>-<line>.py<XY><abiflags>.nbi`, <line>
    the function's first line (its first decorator's). One file looked up, no directory listed."""
    lines = text.splitlines()
    i = next((k for k, line in enumerate(lines) if line.startswith(f"def {fn}(")), None)
    if i is None:
        return False
    while i > 0 and lines[i - 1].startswith("@"):
        i -= 1
    tag = f"py{sys.version_info[0]}{sys.version_info[1]}{getattr(sys, 'abiflags', '')}"
    return (path.parent / "__pycache__" / f"{path.stem}.{fn}-{i + 1}.{tag}.nbi").is_file()


class _File(caching.IndexDataCacheFile):
    """numba's index and data files, sealed with their digest."""

    def __init__(self, cache_path, filename_base, source_stamp, owner: Owner):
        super().__init__(cache_path, filename_base, source_stamp)
        self._owner = owner

    # reading: verified bytes, or None (missing, or set aside now)
    def _read(self, path: str) -> bytes | None:
        try:
            data = cache_store.read(Path(path))
        except cache_store.CacheDamage as e:
            # one line per directory: what makes one file unreadable usually holds for its neighbours
            cache_store.say(f"kernel cache: {path} {e.reason}; not used", once=f"unreadable|{os.path.dirname(path)}")
            return None
        if data is None:
            return None
        nl = data.find(b"\n")
        name = os.path.basename(path).encode()
        if not data.startswith(MAGIC) or nl < 0 or data[len(MAGIC):nl].decode("ascii", "replace") != \
                cache_store.sha256(name + b"\0" + data[nl + 1:]):
            why = "is empty" if not data else "does not match its digest (truncated, changed or not written by vcirun)"
            self._set_aside(path, why)
            return None
        return data[nl + 1:]

    def _set_aside(self, path: str, why: str) -> None:
        # one line per module: the first file set aside is named, the others go to the quarantine quietly
        cache_store.quarantine(Path(path), why, rebuild=f"compiling {self._owner.label} again",
                               quiet=self._owner.announced)
        self._owner.announced = True   # the quarantine line says that it compiles

    def _write(self, path: str, payload: bytes) -> None:
        name = os.path.basename(path).encode()
        head = MAGIC + cache_store.sha256(name + b"\0" + payload).encode() + b"\n"
        cache_store.write_atomic(Path(path), head + payload)

    def _load_index(self):
        payload = self._read(self._index_path)
        if payload is None:
            return {}
        try:
            f = io.BytesIO(payload)
            version = pickle.load(f)
            if version != self._version:
                return {}
            stamp, overloads = pickle.loads(f.read())
            if not isinstance(overloads, dict):
                raise TypeError("index is not a mapping")
        except Exception as e:  # noqa: BLE001 - a checked file numba cannot read: rebuilt
            self._set_aside(self._index_path, f"cannot be read by numba ({type(e).__name__})")
            return {}
        if stamp != self._source_stamp:
            return {}
        return overloads

    def _save_index(self, overloads):
        self._write(self._index_path, pickle.dumps(self._version, protocol=-1)
                    + self._dump((self._source_stamp, overloads)))

    def _load_data(self, name):
        path = self._data_path(name)
        payload = self._read(path)
        if payload is None:
            raise FileNotFoundError(path)   # numba's load() then compiles
        try:
            return pickle.loads(payload)
        except Exception as e:  # noqa: BLE001
            self._set_aside(path, f"cannot be read by numba ({type(e).__name__})")
            raise FileNotFoundError(path) from None

    def _save_data(self, name, data):
        self._write(self._data_path(name), self._dump(data))


class _Cache(caching.FunctionCache):
    _impl_class = _Impl

    def __init__(self, py_func, owner: Owner):
        super().__init__(py_func)
        self._owner = owner
        self._cache_file = _File(self._cache_path, self._impl.filename_base, self._impl.locator.get_source_stamp(),
                                 owner)

    def load_overload(self, sig, target_context):
        try:
            cres = super().load_overload(sig, target_context)
        except Exception as e:  # noqa: BLE001 - checked data numba cannot rebuild: compiled again
            cache_store.say(f"kernel cache: numba could not rebuild its cached code of {self._py_func.__qualname__} "
                            f"({type(e).__name__}); compiling {self._owner.label} again",
                            once=f"rebuild|{self._cache_path}|{self._py_func.__qualname__}")
            self._owner.announced = True
            cres = None
        if cres is None and self._enabled:
            self._owner.compiling(self._py_func.__qualname__)
        return cres

    def save_overload(self, sig, data):
        try:
            super().save_overload(sig, data)
        except (OSError, cache_store.CacheError) as e:
            self._owner.unsaved(self._cache_path, e)


def adopt(mod, path: Path, owner: Owner) -> int:
    """Give every cached numba function defined in the module at `path` the checked cache, and its
    compiles LLVM's optimisation level OPT_LEVEL (`_at_kernel_opt`). Returns how many."""
    from numba.core.dispatcher import Dispatcher

    src = os.path.abspath(path)
    n = 0
    for v in list(vars(mod).values()):
        if not isinstance(v, Dispatcher) or isinstance(getattr(v, "_cache", None), (_Cache, caching.NullCache)) \
                or getattr(v, "_cache", None) is None:
            continue
        if os.path.abspath(v.py_func.__code__.co_filename) != src:
            continue
        v._cache = _Cache(v.py_func, owner)
        v.compile = _at_kernel_opt(v.compile)
        n += 1
    return n


# LLVM's optimisation passes run at level 1 for the kernel cache's modules (numba's default is 3):
# measured on the cart-pendulum's first simulation with an empty cache, CVA 43.5 -> 33.3 s (twice),
# MCVAC 47.0 -> 43.3-46.9 s (noisy), with the loop's time unchanged (within 1 %) and every golden
# trajectory bit for bit (bench/golden.py): numba's module passes run again on every callee linked
# into each function (its design: one library per function), and the extra level-3 rounds bought
# nothing here. Level 0 leaves the kernels uninlined (the CVA loop 11x slower). The target machine
# (instruction selection) keeps numba's level. NUMBA_OPT set in the environment wins.
OPT_LEVEL = 1


def _at_kernel_opt(compile_):
    """A dispatcher's compile with numba's OPT at OPT_LEVEL, under numba's compiler lock (another
    thread's compile never sees it; nested compiles of callees keep it)."""

    def compile(sig):
        from numba.core import config
        from numba.core.compiler_lock import global_compiler_lock

        if "NUMBA_OPT" in os.environ:
            return compile_(sig)
        with global_compiler_lock:
            before = config.OPT
            config.OPT = config._OptLevel(OPT_LEVEL)
            try:
                return compile_(sig)
            finally:
                config.OPT = before

    return compile
