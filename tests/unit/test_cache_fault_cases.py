"""More faults of the kernel cache, the cases of the former fault probe that tests/unit/test_cache_faults.py
does not hold: a shared object replaced by another ELF, a directory or a dangling link, its digest
record missing, garbage or rewritten to match a flipped bit; a scene module without its seal line,
with a line appended, or a directory in its place; numba index files truncated, flipped or in numba's
own unsealed format; a truncated warm-index entry; `kernels` a file; a cache under a file. Each
heals with the bits of the clean run (a second run silent) or ends in one `error:` line naming the
cache; never a signal, a traceback or other bits with exit 0. Same template and helpers as
test_cache_faults (a warm copy per case, `vcirun simulate` in a fresh process)."""
from __future__ import annotations

import hashlib
import os
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_cache_faults import (  # noqa: E402,F401 - the fixtures `template` and `case` are used by name
    RUN,
    case,
    flip,
    healed,
    kern,
    one_error,
    pytestmark,
    scene_module,
    template,
    vcirun,
)


def _dir_for(p: Path):
    p.unlink()
    p.mkdir()
    (p / "x").write_text("x")


def _sidecar(so: Path) -> Path:
    return Path(str(so) + ".sha256")


SO_FAULTS = {
    "another ELF in its place": lambda so, c: shutil.copy("/bin/true", so),
    "a directory in its place": lambda so, c: _dir_for(so),
    "a dangling symbolic link in its place": lambda so, c: (so.unlink(), so.symlink_to(c / "nowhere.so")),
    "a block zeroed": lambda so, c: so.write_bytes((lambda b: b[:4096] + bytes(256) + b[4352:])(so.read_bytes())),
    "its digest record missing": lambda so, c: _sidecar(so).unlink(),
    "its digest record garbage": lambda so, c: _sidecar(so).write_bytes(os.urandom(40)),
    "a flipped bit, the digest record rewritten to match": lambda so, c: (
        flip(so, 0.5), _sidecar(so).write_text(f"{hashlib.sha256(so.read_bytes()).hexdigest()} {so.stat().st_size}\n")),
}


@pytest.mark.parametrize("fault", list(SO_FAULTS))
def test_a_replaced_shared_object_heals(case, fault):
    c, ref = case
    so = kern(c, "vkc_*.so")[0]
    if not _sidecar(so).exists() and "digest" in fault:
        pytest.skip("no digest record beside the shared object")
    SO_FAULTS[fault](so, c)
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref)
    r = vcirun(c, *RUN, "--output", c.parent / "again.npz")
    healed(r, c.parent / "again.npz", ref)
    assert "compiling" not in r.stderr and "kernel cache:" not in r.stderr, r.stderr


MODULE_FAULTS = {
    "its seal line removed": lambda p: p.write_text("".join(p.read_text().splitlines(keepends=True)[:-1])),
    "a line appended": lambda p: p.write_text(p.read_text() + "x = 1\n"),
    "a directory in its place": _dir_for,
}


@pytest.mark.parametrize("fault", list(MODULE_FAULTS))
def test_a_scene_module_out_of_shape_heals(case, fault):
    c, ref = case
    mod = scene_module(c)
    text = mod.read_text()
    MODULE_FAULTS[fault](mod)
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref)
    assert mod.is_file() and mod.read_text() == text


def _unseal(p: Path):
    data = p.read_bytes()
    p.write_bytes(data[data.index(b"\n") + 1:])


NUMBA_FAULTS = {
    "truncated index": lambda p: os.truncate(p, p.stat().st_size // 2),
    "one bit of the index": lambda p: flip(p, 0.5),
    "an index in numba's own (unsealed) format": _unseal,
}


@pytest.mark.parametrize("fault", list(NUMBA_FAULTS))
def test_a_damaged_numba_index_heals(case, fault):
    c, ref = case
    for p in kern(c, "__pycache__/vk_*._p_sys_M-*.nbi"):
        NUMBA_FAULTS[fault](p)
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref)
    r = vcirun(c, *RUN, "--output", c.parent / "again.npz")
    healed(r, c.parent / "again.npz", ref)
    assert "compiling" not in r.stderr and "kernel cache:" not in r.stderr, r.stderr


def test_a_truncated_warm_index_entry_heals(case):
    c, ref = case
    for p in kern(c, "wi_*.json"):
        p.write_text(p.read_text()[: len(p.read_text()) // 2])
    r = vcirun(c, *RUN, "--output", c.parent / "out.npz")
    healed(r, c.parent / "out.npz", ref, said="wi_")


def test_kernels_as_a_file_is_one_error_line_and_clear_removes_it(case):
    c, _ = case
    shutil.rmtree(c / "kernels")
    (c / "kernels").write_text("x")
    one_error(vcirun(c, *RUN), str(c))
    r = vcirun(c, "cache", "clear")
    assert r.returncode == 0 and not (c / "kernels").exists(), r.stderr


def test_a_cache_under_a_file_is_one_error_line(tmp_path):
    import subprocess

    from test_cache_faults import CLI, _env

    f = tmp_path / "afile"
    f.write_text("x")
    (tmp_path / "home").mkdir()
    r = subprocess.run([sys.executable, "-c", CLI, *RUN], env=_env(f / "sub", tmp_path / "home"),
                       capture_output=True, text=True, timeout=300, cwd=str(tmp_path))
    one_error(r, "VCIRUN_CACHE_DIR")
