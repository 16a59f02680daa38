"""Faults of the kernel cache (vcirun.codegen.cache_store, .numba_cache, .c_link, .cache_lock, .cache).

On a copy of one warm cache, every fault either heals with the bits of the clean run (exit 0, a line
that says what was set aside) or ends in one `error:` line naming the cache and the fix; never a
crash signal, a traceback or a different result with exit 0.

One template cache per test session: the cart-pendulum's CVA kernels with every leaf kernel in C
(VCIRUN_C_MIN_STATEMENTS=0, so the scene module loads a shared object), built by `vcirun simulate`
in a subprocess. The shared core (the same for every scene, compiled once per machine) is copied
from the suite's cache when that has it. Each case copies the template and runs `vcirun simulate`
in a fresh process. Faults that make numba compile the core again (~1 min each) are marked slow.
"""
from __future__ import annotations

import contextlib
import fcntl
import glob
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from vcirun.codegen import build, c_link, cache_lock, cache_store, cc
from vcirun.codegen.kernel_cache import KernelCache

ROOT = Path(build._PKG).parent
pytestmark = pytest.mark.skipif(cc.compiler() is None, reason="no C compiler: the faults of shared objects need one")

RUN = ["simulate", "--system", "cart_pendulum", "--method", "CVA", "--beta", "3.2", "--T", "1"]
CLI = "import sys; from vcirun.cli.main import app; sys.argv[0] = 'vcirun'; app()"


def _env(cache, home, **extra) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "VCIRUN_"))}
    env.update(PYTHONPATH=str(ROOT), VCIRUN_CACHE_DIR=str(cache), VCIRUN_C_MIN_STATEMENTS="0", HOME=str(home))
    env.update({k: str(v) for k, v in extra.items()})
    return env


def vcirun(cache, *args, home=None, timeout=900, **env):
    home = home or Path(cache).parent / "home"
    Path(home).mkdir(parents=True, exist_ok=True)
    return subprocess.run([sys.executable, "-c", CLI, *map(str, args)], env=_env(cache, home, **env),
                          capture_output=True, text=True, timeout=timeout, cwd=str(Path(cache).parent))


def arrays(path) -> dict:
    with np.load(path) as z:
        return {k: z[k].copy() for k in z.files}


# --- the template -----------------------------------------------------------------------------------

def _seed_core(dest: Path) -> None:
    """Copy the CVA core of the cart-pendulum (module and numba files) from the suite's cache, if it has
    them verified."""
    from vcirun.codegen.cache import core_key_for
    from vcirun.methods.table import METHODS
    from vcirun.scenes.registry import get_scene

    try:
        src = build.cache_dir()
        key = core_key_for(get_scene("cart_pendulum"), METHODS["CVA"].kernel_set())
    except cache_store.CacheError:
        return
    files = [src / f"core_{key}.py", *sorted((src / "__pycache__").glob(f"core_{key}.*"))]
    if len(files) < 3 or not all(f.is_file() for f in files):
        return
    (dest / "kernels" / "__pycache__").mkdir(parents=True, exist_ok=True)
    for f in files:
        shutil.copy2(f, dest / "kernels" / f.relative_to(src))


@pytest.fixture(scope="session")
def template(tmp_path_factory):
    """(template cache, reference arrays): built once for all xdist workers (under a file lock)."""
    uid = os.environ.get("PYTEST_XDIST_TESTRUNUID")   # one template for the workers of this run
    shared = tmp_path_factory.getbasetemp().parent if uid else tmp_path_factory.getbasetemp()
    base = shared / f"cache_faults_template_{uid or 'run'}"
    with open(shared / f"cache_faults_template_{uid or 'run'}.lock", "w") as lk:
        fcntl.flock(lk, fcntl.LOCK_EX)
        ref = base / "ref.npz"
        if not ref.is_file():
            shutil.rmtree(base, ignore_errors=True)
            (base / "cache").mkdir(parents=True)
            _seed_core(base / "cache")
            t0 = time.perf_counter()
            # compiled here, not in a background process: nothing may write into the template after
            # this fixture returns (the cases copy it, on both xdist workers)
            r = vcirun(base / "cache", *RUN, "--output", base / "ref0.npz", VCIRUN_TIER="compiled")
            assert r.returncode == 0, r.stderr[-3000:]
            print(f"cache-fault template built in {time.perf_counter() - t0:.1f} s: {r.stderr.strip()}")
            r = vcirun(base / "cache", *RUN, "--output", ref)   # warm, default tier: the reference
            assert r.returncode == 0 and "compiling" not in r.stderr and "interpreted" not in r.stderr, \
                r.stderr[-3000:]
            assert not list((base / "cache" / "kernels").glob("bg_*.log")), "a background compile was started"
            assert arrays(ref)["q"].tobytes() == arrays(base / "ref0.npz")["q"].tobytes()
            for lock in (base / "cache" / "kernels").glob("*.lock"):
                lock.write_bytes(b"")
    return base / "cache", arrays(ref)


@pytest.fixture
def case(template, tmp_path):
    """A copy of the template: (cache directory, reference arrays)."""
    c = tmp_path / "cache"
    shutil.copytree(template[0], c, symlinks=True)
    return c, template[1]


def kern(c, pattern) -> list[Path]:
    found = sorted(Path(p) for p in glob.glob(str(c / "kernels" / pattern)))
    assert found, pattern
    return found


def scene_module(c) -> Path:
    return next(p for p in kern(c, "vk_*.py") if "_bind(__file__" in p.read_text(errors="replace"))


def flip(p: Path, frac: float, bit: int = 3) -> None:
    b = bytearray(p.read_bytes())
    b[int(len(b) * frac)] ^= 1 << bit
    p.write_bytes(bytes(b))


def healed(r, out: Path, ref: dict, said: str | None = None) -> None:
    """Exit 0, no traceback, the reference bits; `said`: a line of stderr names it."""
    assert "Traceback" not in r.stderr and "Aborted" not in r.stderr, r.stderr[-3000:]
    assert r.returncode == 0, r.stderr[-3000:]
    got = arrays(out)
    assert set(got) == set(ref)
    for k in ref:
        assert got[k].tobytes() == ref[k].tobytes(), k
    if said is not None:
        assert said in r.stderr, r.stderr


def one_error(r, *words) -> str:
    assert r.returncode == 1, (r.returncode, r.stderr[-3000:])
    assert "Traceback" not in r.stderr and "Aborted" not in r.stderr, r.stderr[-3000:]
    errors = [line for line in r.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, r.stderr
    for w in words:
        assert w in errors[0], errors[0]
    return errors[0]


# --- damaged files heal with the same bits ----------------------------------------------------------

SO_FAULTS = {
    "truncated": lambda p: os.truncate(p, 9000 if p.stat().st_size > 9000 else p.stat().st_size // 2),
    "one bit of code": lambda p: flip(p, 0.3),
    "one bit of a constant": lambda p: flip(p, 0.7, 0),
    "empty": lambda p: os.truncate(p, 0),
    "missing": lambda p: p.unlink(),
}


@pytest.mark.parametrize("fault", list(SO_FAULTS))
def test_a_damaged_shared_object_is_rebuilt(case, fault):
    c, ref = case
    so = kern(c, "vkc_*.so")[0]
    SO_FAULTS[fault](so)
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref, said=so.name)
    assert c_link.recorded_digest(so) is not None   # rebuilt and recorded
    r = vcirun(c, *RUN, "--output", c.parent / "again.npz")
    healed(r, c.parent / "again.npz", ref)
    assert "kernel cache:" not in r.stderr and "compiling" not in r.stderr


CONSTANT = ("FULL_FRACS = np.array([1.0]", "FULL_FRACS = np.array([0.9]")   # a full step's fraction of h

MODULE_FAULTS = {
    "one constant edited": lambda p: p.write_text(p.read_text().replace(*CONSTANT, 1)),
    "empty": lambda p: os.truncate(p, 0),
    "half written": lambda p: os.truncate(p, p.stat().st_size // 2),
    "one bit": lambda p: flip(p, 0.4, 1),
    "missing": lambda p: p.unlink(),
}


@pytest.mark.parametrize("fault", list(MODULE_FAULTS))
def test_a_changed_scene_module_is_generated_again(case, fault):
    c, ref = case
    mod = scene_module(c)
    text = mod.read_text()
    assert CONSTANT[0] in text
    MODULE_FAULTS[fault](mod)
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref, said=None if fault == "missing" else mod.name)
    assert mod.read_text() == text   # the same text again
    if fault != "missing":
        assert list((c / "quarantine").glob(mod.name + ".*"))


NUMBA_FAULTS = {
    "empty index": ("nbi", lambda p: os.truncate(p, 0)),
    "empty data": ("nbc", lambda p: os.truncate(p, 0)),
    "truncated data": ("nbc", lambda p: os.truncate(p, p.stat().st_size // 2)),
    "one bit of data": ("nbc", lambda p: flip(p, 0.6)),
    "missing index": ("nbi", lambda p: p.unlink()),
    "other function's data": ("nbc", None),
}


@pytest.mark.parametrize("fault", list(NUMBA_FAULTS))
def test_a_damaged_numba_file_is_compiled_again(case, fault):
    """The scene module's numba files (a few seconds to compile again); the core's are the slow test."""
    c, ref = case
    ext, how = NUMBA_FAULTS[fault]
    files = kern(c, f"__pycache__/vk_*._p_sys_M-*.{ext}")
    if how is None:
        other = kern(c, "__pycache__/vk_*._p_sys_V-*.nbc")[0]
        shutil.copy(other, files[0])
    else:
        for f in files:
            how(f)
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref, said="sys_M")
    assert len([line for line in r.stderr.splitlines() if line.strip()]) <= 2, r.stderr
    r = vcirun(c, *RUN, "--output", c.parent / "again.npz")
    healed(r, c.parent / "again.npz", ref)
    assert "compiling" not in r.stderr and "kernel cache:" not in r.stderr, r.stderr


def _edit_index(c, fn):
    for p in kern(c, "wi_*.json"):
        p.write_text(fn(p.read_text()))


INDEX_FAULTS = {
    "points at another module": lambda c: _edit_index(
        c, lambda t: re.sub(r'"module": ?"[0-9a-f]{20}"', '"module": "' + "0" * 20 + '"', t)),
    "a parameter edited": lambda c: _edit_index(c, lambda t: t.replace('"m2", 0.2', '"m2", 0.25')),
    "empty": lambda c: _edit_index(c, lambda t: ""),
    "not JSON": lambda c: _edit_index(c, lambda t: "[1, 2"),
}


@pytest.mark.parametrize("fault", list(INDEX_FAULTS))
def test_a_changed_warm_index_entry_is_written_again(case, fault):
    c, ref = case
    INDEX_FAULTS[fault](c)
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref, said="wi_")
    entry = json.loads(kern(c, "wi_*.json")[0].read_text())
    assert cache_store.unseal_json(json.dumps(entry).encode())["module"] != "0" * 20


def test_a_changed_core_file_is_written_again(case):
    c, ref = case
    core = kern(c, "core_*.py")[0]
    text = core.read_text()
    core.write_text(text.replace("0.5", "0.25", 1))
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref, said=core.name)
    assert core.read_text() == text and "compiling" not in r.stderr


def test_advisory_files_and_leftovers(case):
    """Garbage build times and lock files change nothing; the leftovers of killed processes go."""
    c, ref = case
    (c / "build_times.json").write_text('{"scene|CVA[SVC]|2": "x", "core|a": [1], "CVA|x": 2}')
    locks = kern(c, "*.lock")
    locks[0].write_bytes(os.urandom(300))
    locks[-1].unlink()
    locks[-1].mkdir()
    dead = c / "kernels" / f".vk_x.py.tmp.999999999.{cache_store.host_tag()}.0000"
    dead.write_text("half")
    build_dir = c / "kernels" / f"{cache_store.BUILD_DIR_MARK}999999999.{cache_store.host_tag()}.0000"
    build_dir.mkdir()
    (build_dir / "u0.c").write_text("int x;")
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref)
    assert r.stderr.strip() == ""
    assert cache_store.sweep_stale(c / "kernels") == 0 or not dead.exists()
    r = vcirun(c, "cache", "clear")   # a compile leaves no temporary file; clear removes the rest
    assert r.returncode == 0 and not dead.exists() and not build_dir.exists(), r.stderr


# --- an unusable cache is one error line ------------------------------------------------------------

def test_an_empty_cache_variable_is_refused(tmp_path):
    for args in (RUN, ["cache", "info"], ["cache", "clear"]):
        r = vcirun(tmp_path / "c", *args, VCIRUN_CACHE_DIR="")
        one_error(r, "VCIRUN_CACHE_DIR", "empty")
    assert not (tmp_path / "kernels").exists()


def test_a_file_where_the_cache_should_be(tmp_path):
    c = tmp_path / "cachefile"
    c.write_text("x")
    for args in (RUN, ["cache", "info"], ["cache", "clear"]):
        one_error(vcirun(c, *args), str(c), "VCIRUN_CACHE_DIR")
    d = tmp_path / "c2"
    d.mkdir()
    (d / "kernels").write_text("x")
    one_error(vcirun(d, *RUN), str(d / "kernels"), "vcirun cache clear")
    r = vcirun(d, "cache", "clear")
    assert r.returncode == 0 and not (d / "kernels").exists(), r.stderr


@contextlib.contextmanager
def read_only(path: Path):
    """`path` read-only for this test's processes: a read-only bind mount as root, else permissions."""
    if os.geteuid() != 0:
        modes = {p: p.stat().st_mode for p in [path, *path.rglob("*")] if not p.is_symlink()}
        for p in modes:
            p.chmod(modes[p] & ~0o222)
        try:
            yield
        finally:
            for p, m in modes.items():
                p.chmod(m)
        return
    ok = subprocess.run(["mount", "--bind", str(path), str(path)], capture_output=True).returncode == 0
    if ok and subprocess.run(["mount", "-o", "remount,ro,bind", str(path)], capture_output=True).returncode != 0:
        subprocess.run(["umount", str(path)], capture_output=True)
        ok = False
    if not ok:
        pytest.skip("running as root without mount: no way to make a directory read-only")
    try:
        yield
    finally:
        subprocess.run(["umount", str(path)], capture_output=True)


def test_a_read_only_warm_cache_is_loaded_not_recompiled(case, tmp_path):
    c, ref = case
    home = tmp_path / "home"
    with read_only(c):
        r = vcirun(c, *RUN, "--output", tmp_path / "out.npz", home=home, NUMBA_CACHE_DIR=tmp_path / "nb")
        healed(r, tmp_path / "out.npz", ref)
        assert "compiling" not in r.stderr and r.stderr.strip() == "", r.stderr
        r = vcirun(c, "cache", "info", home=home)
        assert r.returncode == 0 and "compiled modules" in r.stdout
        r = vcirun(c, "cache", "clear", home=home)
        err = one_error(r, str(c), "could not remove")
        assert "removed 0 files" in err
        assert kern(c, "vk_*.py")
        # what cannot be healed in a read-only cache is an error, not a traceback
        r = vcirun(c, "simulate", "--system", "double_pendulum", "--method", "CVA", "--T", "0.1", home=home)
        one_error(r, "read-only", "VCIRUN_CACHE_DIR")
    assert not (home / ".cache" / "numba").exists() and not (tmp_path / "nb").exists()


def test_numba_cache_dir_does_not_move_the_kernels(case, tmp_path):
    c, ref = case
    nb = tmp_path / "numba_cache"
    r = vcirun(c, *RUN, "--output", tmp_path / "out.npz", NUMBA_CACHE_DIR=nb)
    healed(r, tmp_path / "out.npz", ref)
    assert "compiling" not in r.stderr and not list(nb.rglob("*.nb*"))


def test_a_full_disk_is_one_error_line(case, tmp_path):
    """The scene module must be written on a full disk (a small tmpfs). On the compiled tier that is
    one error line; on the default tier the run is answered by the interpreted tier (the same bits)
    while the compiled tier cannot be built; once there is space again, the compiled tier heals."""
    c, ref = case
    if os.geteuid() != 0:
        pytest.skip("mounting a small file system needs root")
    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16m", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs")
    try:
        shutil.copytree(c / "kernels", mnt / "kernels", ignore=shutil.ignore_patterns("vk_*", "vkc_*", "wi_*"))
        free = shutil.disk_usage(mnt).free
        with open(mnt / "filler", "wb") as f:
            f.write(b"\0" * (free - 4096))
        r = vcirun(mnt, *RUN, "--output", tmp_path / "out.npz", VCIRUN_TIER="compiled")
        one_error(r, str(mnt), "space")
        r = vcirun(mnt, *RUN, "--output", tmp_path / "auto.npz")
        healed(r, tmp_path / "auto.npz", ref, said="interpreted tier")
        (mnt / "filler").unlink()
        r = vcirun(mnt, *RUN, "--output", tmp_path / "out.npz")
        healed(r, tmp_path / "out.npz", ref)
    finally:
        # the default tier's background compile may still hold the file system: detached lazily then,
        # so no mount outlives the test (pytest's later clean-up of tmp_path would find it busy)
        if subprocess.run(["umount", str(mnt)], capture_output=True).returncode:
            subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


# --- locks ------------------------------------------------------------------------------------------

HOLDER = r"""
import os, subprocess, sys, time, signal
from vcirun.codegen import cache_lock
mode, path = sys.argv[1], sys.argv[2]
with cache_lock.held(path, "the test's compile"):
    print("held", flush=True)
    if mode == "stop":
        os.kill(os.getpid(), signal.SIGSTOP)
    elif mode == "orphan":   # a child keeps the locked descriptor after this process is gone
        fd = next(int(f) for f in os.listdir("/proc/self/fd") if os.path.realpath(f"/proc/self/fd/{f}") == path)
        os.set_inheritable(fd, True)
        subprocess.Popen(["sleep", "60"], pass_fds=(fd,))
        os._exit(0)
    else:
        time.sleep(float(mode))
"""


@contextlib.contextmanager
def holder(mode: str, path: Path):
    p = subprocess.Popen([sys.executable, "-c", HOLDER, mode, str(path)], stdout=subprocess.PIPE, text=True,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)), start_new_session=True)
    try:
        assert p.stdout.readline().strip() == "held"
        yield p
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGCONT)
            os.killpg(p.pid, signal.SIGKILL)
        p.wait()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="process states from /proc")
@pytest.mark.parametrize("mode", ["stop", "orphan", "busy"])
def test_a_lock_names_its_holder(tmp_path, monkeypatch, mode):
    """A stopped holder is reported with the fix, a gone one taken over at once, a working one named
    after a few seconds while the waiter waits for it."""
    lines = []
    monkeypatch.setattr(cache_store, "LISTENERS", [lambda m: lines.append(m) or True])
    monkeypatch.setattr(cache_lock, "NOTE_AFTER_S", 0.5)
    path = (tmp_path / "x.lock").resolve()
    with holder("4" if mode == "busy" else mode, path) as p:
        if mode == "orphan":
            p.wait()
        t0 = time.monotonic()
        with cache_lock.held(path, "mine"):
            waited = time.monotonic() - t0
    text = "\n".join(lines)
    assert len(lines) == 1, text
    assert str(p.pid) in text and "the test's compile" in text, text
    if mode == "stop":
        assert "is stopped" in text and f"kill -CONT {p.pid}" in text, text
    elif mode == "orphan":
        assert "no longer runs" in text, text
    else:
        assert text.startswith("waiting for process") and waited > 1.0, text


# --- NUMBA_DISABLE_JIT and keys ---------------------------------------------------------------------

@pytest.mark.parametrize("method", ["CVA", pytest.param("MCVAC", marks=pytest.mark.slow)])
def test_uncompiled_runs_call_the_c_kernels(case, tmp_path, method):
    """NUMBA_DISABLE_JIT=1 runs the module as Python, its C kernels through ctypes: the numbers of the
    compiled run to round-off."""
    c, ref = case
    run = ["simulate", "--system", "cart_pendulum", "--method", method, "--beta", "3.2", "--T", "0.3"]
    r = vcirun(c, *run, "--output", tmp_path / "jit.npz")
    assert r.returncode == 0, r.stderr[-3000:]
    r = vcirun(c, *run, "--output", tmp_path / "py.npz", NUMBA_DISABLE_JIT=1)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr[-3000:]
    a, b = arrays(tmp_path / "jit.npz"), arrays(tmp_path / "py.npz")
    assert "_bind(__file__" in "".join(p.read_text() for p in kern(c, "vk_*.py"))
    np.testing.assert_allclose(b["q"], a["q"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(b["p"], a["p"], rtol=0, atol=1e-12)
    assert len(a["impacts"]) == len(b["impacts"])


def test_a_core_key_does_not_depend_on_the_c_compiler(monkeypatch, tmp_path):
    from vcirun.methods.table import METHODS
    from vcirun.scenes.registry import get_scene

    ks = METHODS["MCVAC"].kernel_set()
    s = get_scene("cart_pendulum")
    kc = KernelCache()
    core, mod = kc.core_key_of(ks, 2), kc.module_key(s, ks)
    wrapper = tmp_path / "bin" / "cc"
    wrapper.parent.mkdir()
    wrapper.write_text(f"#!/bin/sh\nexec {cc.compiler()} \"$@\"\n")
    wrapper.chmod(0o755)
    monkeypatch.setenv("CC", str(wrapper))
    kc = KernelCache()   # (a new process: no key remembered)
    assert kc.core_key_of(ks, 2) == core
    assert kc.module_key(s, ks) != mod   # the scene's C kernels do depend on it


# --- slow: faults that recompile the core, kills ----------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("fault", ["empty index", "truncated data", "one bit of data"])
def test_a_damaged_core_numba_file_is_compiled_again(case, fault):
    c, ref = case
    ext, how = NUMBA_FAULTS[fault]
    for f in kern(c, f"__pycache__/core_*.integrate-*.{ext}"):
        how(f)
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref, said="integrate")


@pytest.mark.slow
def test_a_file_in_place_of_numbas_directory_is_set_aside(case):
    """Everything numba cached is gone (the core compiles again), and saved again in a new directory."""
    c, ref = case
    nb = c / "kernels" / "__pycache__"
    shutil.rmtree(nb)
    nb.write_text("x")
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref, said="__pycache__ is not a directory")
    assert nb.is_dir() and list(nb.glob("*.nbi"))
    r = vcirun(c, *RUN, "--output", c.parent / "again.npz")
    healed(r, c.parent / "again.npz", ref)
    assert r.stderr.strip() == "", r.stderr


@pytest.mark.slow
def test_a_kill_during_the_c_compile_leaves_nothing_behind(case):
    c, ref = case
    for f in kern(c, "vk_*.py") + kern(c, "vkc_*") + kern(c, "wi_*.json"):
        f.unlink()
    p = subprocess.Popen([sys.executable, "-c", CLI, *RUN], env=_env(c, c.parent / "home"), stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL, start_new_session=True)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 300 and not glob.glob(str(c / "kernels" / f"{cache_store.BUILD_DIR_MARK}*" / "*.c")):
        time.sleep(0.01)
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    assert glob.glob(str(c / "kernels" / f"{cache_store.BUILD_DIR_MARK}*"))
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref)
    assert not glob.glob(str(c / "kernels" / f"{cache_store.BUILD_DIR_MARK}*"))


@pytest.mark.slow
def test_uncompiled_runs_of_every_method(case, tmp_path):
    from vcirun.methods.table import METHODS

    c, _ = case
    for method in METHODS:
        run = ["simulate", "--system", "cart_pendulum", "--method", method, "--beta", "3.2", "--T", "0.3"]
        r = vcirun(c, *run, "--output", tmp_path / "jit.npz")
        assert r.returncode == 0, (method, r.stderr[-3000:])
        r = vcirun(c, *run, "--output", tmp_path / "py.npz", NUMBA_DISABLE_JIT=1)
        assert r.returncode == 0, (method, r.stderr[-3000:])
        a, b = arrays(tmp_path / "jit.npz"), arrays(tmp_path / "py.npz")
        np.testing.assert_allclose(b["q"], a["q"], rtol=0, atol=1e-12, err_msg=method)
