"""The C kernels' shared object in the kernel cache: built once, recorded with its digest, checked
before every load, and bound into the generated module by name.

`c_kernels(text, out_dir)` translates the leaf kernels of a generated module (vcirun.codegen.c_emit),
and compiles them into `out_dir/vkc_<hash>.so` unless a verified copy is there: the hash names the C
code and the compiler (so modules with the same kernels share the file), and the sidecar
`vkc_<hash>.so.sha256` records its digest. A new shared object is loaded once in a subprocess before
it is published (a file that would crash the loader never reaches the cache), then renamed into
place atomically, under a compile lock (vcirun.codegen.cache_lock) so that parallel processes build
it once. A copy that fails its digest is quarantined and built again.

In the module each translated kernel is replaced by a binding of the same name and signature that
calls the C symbol by name (`numba.types.ExternalFunction`), so numba's cached callers stay valid in
a new process. The module's header calls `bind(__file__, so_name, digest)`: the shared object is
loaded only if its bytes have the digest the module was generated with (else `CacheDamage`, and the
build rebuilds the entry); a truncated or altered file is never mapped.

With NUMBA_DISABLE_JIT=1 the same module runs as Python: `bind` then returns the Python equivalents
of the binding's two pieces, the data pointer of an array (`_py_cptr`) and a ctypes call of the C
symbol (`_py_extern`), so the kernels compute what the compiled module computes.
"""
from __future__ import annotations

import ctypes
import errno
import os
import re
import subprocess
import sys
import time
import warnings
from pathlib import Path

from numba import config, types
from numba.core import errors
from numba.extending import intrinsic

from . import cache_store, cc
from .c_emit import Translation, translate_module
from .c_translate import CKernel

C_LOG: list[dict] = []  # per module: kernels in C, kernels left in numba (and why), compile seconds
_SIDECAR = ".sha256"
_BIND_RE = re.compile(r"^_cptr, _ExternalFunction = _bind\(__file__, '([A-Za-z0-9_.]+)', '([0-9a-f]{64})'\)$", re.MULTILINE)


# --- building and verifying the shared object -------------------------------------------------------

def _sidecar(so: Path) -> Path:
    return so.with_name(so.name + _SIDECAR)


def recorded_digest(so: Path) -> str | None:
    """The digest of a shared object whose bytes match its sidecar; None when either is missing. A
    mismatch is quarantined (both files) and said."""
    try:
        rec = cache_store.read(_sidecar(so))
        if rec is None or not so.exists():
            return None
        digest = rec.decode().split()[0]
        got = cache_store.file_sha256(so)
    except (cache_store.CacheDamage, OSError, UnicodeDecodeError, IndexError) as e:
        reason = e.reason if isinstance(e, cache_store.CacheDamage) else "has an unreadable digest record"
        set_aside(so, reason)
        return None
    if got != digest:
        set_aside(so, "does not match its recorded digest (damaged)")
        return None
    return digest


def set_aside(so: Path, reason: str) -> None:
    """Quarantine a shared object (said on one line) and drop its digest record."""
    if so.exists():
        cache_store.quarantine(so, reason, rebuild="compiling it again")
    try:
        os.unlink(_sidecar(so))
    except OSError:
        pass


def _check_loads(path: Path) -> None:
    """Load the shared object in a subprocess: a file the dynamic loader cannot map fails there."""
    code = "import ctypes, sys; ctypes.CDLL(sys.argv[1])"
    r = subprocess.run([sys.executable, "-I", "-S", "-c", code, str(path)], capture_output=True, text=True,
                       timeout=120, check=False)
    if r.returncode != 0:
        raise cc.CompileError(f"the linked {path.name} does not load (status {r.returncode}): "
                              f"{r.stderr.strip()[-500:]}")


def _no_space(e: BaseException) -> bool:
    if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        return True
    text = str(e)
    return "No space left on device" in text or "File too large" in text or "Disk quota exceeded" in text


def build_shared_object(tr: Translation, so: Path, entry: dict) -> str | None:
    """The digest of `so` holding tr's kernels: the verified copy, or one compiled now. None when the C
    compiler fails (the kernels then stay numba source, with a warning). A full disk is a CacheError."""
    from .cache_lock import held

    digest = recorded_digest(so)
    if digest is not None:
        entry["reused"] = True
        return digest
    with held(so.with_name(so.stem + ".lock"), f"the C kernels {so.name}"):
        digest = recorded_digest(so)   # built by the process we waited for
        if digest is not None:
            entry["reused"] = True
            return digest
        t1 = time.perf_counter()
        try:
            cc.compile_shared(tr.units(cc.opt_level), so, check=_check_loads)
        except (cc.CompileError, OSError, subprocess.SubprocessError) as e:
            if _no_space(e):
                raise cache_store.CacheError(
                    f"kernel cache {so.parent.parent}: the C compiler ran out of space ({' '.join(str(e).split())[:200]}): "
                    f"free space on its disk, or set {cache_store.ENV} to a directory on another disk") from None
            warnings.warn(f"C kernels: the C compiler failed, the kernels stay in numba ({e})", RuntimeWarning)
            entry["error"] = str(e)
            return None
        digest = cache_store.file_sha256(so)
        cache_store.write_atomic(_sidecar(so), f"{digest} {so.stat().st_size}\n", what=_sidecar(so).name)
        entry["compile_s"] = time.perf_counter() - t1
    return digest


def c_kernels(text: str, out_dir) -> str:
    """Generated numba `text` with its leaf kernels compiled by the system C compiler into
    out_dir/<prefix>.so (a verified copy is reused) and bound by name; `text` unchanged when nothing
    translates, and (with a warning) when the compiler fails: numba is the fallback."""
    t0 = time.perf_counter()
    tr = translate_module(text, salt=cc.identity(), min_stmts=cc.min_statements())
    entry = {"c": [k.name for k in tr.kernels], "numba": dict(tr.skipped), "translate_s": time.perf_counter() - t0,
             "compile_s": 0.0, "reused": False}
    C_LOG.append(entry)
    if not tr.kernels:
        return text
    so = Path(out_dir) / (tr.prefix.rstrip("_") + ".so")
    digest = build_shared_object(tr, so, entry)
    if digest is None:
        return text
    return replace_kernels(text, tr, so.name, digest)


def shared_objects(module_text: str) -> dict:
    """{shared object name: digest} that a generated module loads."""
    return {m.group(1): m.group(2) for m in _BIND_RE.finditer(module_text)}


_verified: dict = {}   # path -> (inode, size, mtime) whose bytes matched in this process


def verify(path: Path, digest: str) -> None:
    """CacheDamage unless the file at `path` has this digest (once per file version and process)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise cache_store.CacheDamage(path, "is missing") from None
    except OSError as e:
        raise cache_store.CacheDamage(path, f"cannot be read ({e.strerror or e})") from None
    stamp = (st.st_ino, st.st_size, st.st_mtime_ns)
    if _verified.get(str(path)) == stamp:
        return
    try:
        got = cache_store.file_sha256(path)
    except OSError as e:
        raise cache_store.CacheDamage(path, f"cannot be read ({e.strerror or e})") from None
    if got != digest:
        raise cache_store.CacheDamage(path, "does not match the digest its module was generated with (damaged)")
    _verified[str(path)] = stamp


# --- binding (the generated module's header calls `bind`) --------------------------------------------

@intrinsic
def cptr(typingctx, arr):
    """The data pointer of a C-contiguous float64 array (what a C kernel takes)."""
    if not (isinstance(arr, types.Array) and arr.dtype == types.float64 and arr.layout == "C"):
        raise errors.TypingError(f"C kernel argument: expected a C-contiguous float64 array, got {arr}")

    def codegen(context, builder, signature, args):
        return context.make_array(arr)(context, builder, args[0]).data

    return types.CPointer(types.float64)(arr), codegen


def _py_cptr(arr):
    import numpy as np

    if not (isinstance(arr, np.ndarray) and arr.dtype == np.float64 and arr.flags.c_contiguous):
        raise TypeError(f"C kernel argument: expected a C-contiguous float64 array, got {type(arr).__name__} "
                        f"{getattr(arr, 'dtype', '')}")
    return arr.ctypes.data


_CTYPES = {types.float64: ctypes.c_double, types.int64: ctypes.c_int64}


def _ctype(t):
    if isinstance(t, types.CPointer):
        return ctypes.c_void_p
    return _CTYPES[t]


def _py_extern(lib, symbol: str, sig):
    """The C symbol as a Python function with the ExternalFunction's signature (ctypes)."""
    fn = getattr(lib, symbol)
    fn.restype = _ctype(sig.return_type)
    fn.argtypes = [_ctype(a) for a in sig.args]

    def call(*args):
        return fn(*args)

    call.__name__ = symbol
    return call


_loaded_so: dict = {}


def bind(module_file: str, so_name: str, digest: str):
    """(pointer function, external-function maker) for a module whose C kernels are in `so_name` beside
    it: the file is loaded only if it has `digest`; CacheDamage otherwise."""
    path = Path(os.path.dirname(os.path.abspath(module_file))) / so_name
    verify(path, digest)
    if config.DISABLE_JIT:
        lib = _loaded_so.get(str(path))
        if lib is None:
            lib = _loaded_so[str(path)] = ctypes.CDLL(str(path))
        return _py_cptr, lambda symbol, sig: _py_extern(lib, symbol, sig)
    if str(path) not in _loaded_so:
        from llvmlite import binding

        binding.load_library_permanently(str(path))
        _loaded_so[str(path)] = True
    return cptr, types.ExternalFunction


def binding_header(so_name: str, digest: str) -> str:
    """Module-level code of a module with C kernels: the checked load of the shared object and the two
    names the bindings use."""
    return f'''
# --- C kernels (vcirun.codegen.c_link): {so_name} is loaded only if it has the digest below; the
# kernels are bound by name, so numba's cache of the callers stays valid ---
from numba import types as _t
from vcirun.codegen.c_link import bind as _bind

_cptr, _ExternalFunction = _bind(__file__, {so_name!r}, {digest!r})
_F8P = _t.CPointer(_t.float64)
'''


def binding_source(k: CKernel, prefix: str) -> str:
    """The numba function that replaces kernel k: same name and signature, calls the C symbol."""
    ptypes, cargs = [], []
    for a, kind in k.args:
        if kind == "-":
            continue
        if kind == "s":
            ptypes.append("_t.float64")
            cargs.append(a)
        else:
            ptypes.append("_F8P")
            cargs.append(f"_cptr({a})")
            if kind == "2":
                ptypes.append("_t.int64")
                cargs.append(f"{a}.shape[1]")
    rt = "_t.float64" if k.returns == "double" else "_t.int64"
    ext = f"_c_{k.name}"
    doc = f"    {'C kernel ' + prefix + k.name + (': ' + k.docstring.splitlines()[0] if k.docstring else '')!r}\n"
    return (f"{ext} = _ExternalFunction({prefix + k.name!r}, {rt}({', '.join(ptypes)}))\n\n\n"
            '@njit(cache=True, nogil=True, error_model="numpy", inline="always")\n'
            f"def {k.name}({', '.join(a for a, _ in k.args)}):\n" + doc
            + f"    return {ext}({', '.join(cargs)})\n")


def replace_kernels(text: str, tr: Translation, so_name: str, digest: str) -> str:
    """`text` with every translated kernel replaced by its binding (the checked loader of the shared
    object `so_name` before the first one)."""
    lines = text.split("\n")
    by_start = {s: (e, name) for name, (s, e) in tr.spans.items()}
    ks = {k.name: k for k in tr.kernels}
    out, i = [], 0
    header = binding_header(so_name, digest)
    while i < len(lines):
        if i in by_start:
            e, name = by_start[i]
            if header is not None:
                out.append(header)
                header = None
            out.append(binding_source(ks[name], tr.prefix))
            i = e
            continue
        out.append(lines[i])
        i += 1
    return "\n".join(out)
