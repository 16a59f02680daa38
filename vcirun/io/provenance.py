"""Where a results file came from: the versions, git commit and platform stored as root attributes,
and the UTC time stamps of its history.
"""
from __future__ import annotations

import datetime as _dt
import platform
import subprocess
from importlib import metadata
from pathlib import Path

import h5py

__all__ = ["now_iso", "git_commit", "environment_attrs"]


def now_iso() -> str:
    """The current UTC time, ISO 8601 to the second."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _version(dist: str) -> str:
    """The installed version of a distribution: the Version line of its metadata's header (what
    importlib.metadata.version returns, without parsing the whole file with the email parser: ~7 ms
    for scipy's)."""
    try:
        text = metadata.distribution(dist).read_text("METADATA") or ""
    except metadata.PackageNotFoundError:
        return ""
    for line in text.splitlines():
        if not line.strip():
            break   # the end of the header
        if line.startswith("Version:"):
            return line.split(":", 1)[1].strip()
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return ""


def git_commit() -> tuple[str, bool | None]:
    """(commit, dirty) of the repository holding the vcirun package, or ('', None). Read-only git calls."""
    start = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "-C", str(start), "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=5, check=True).stdout.strip()
        status = subprocess.run(["git", "--no-optional-locks", "-C", str(start), "status", "--porcelain",
                                 "--untracked-files=no"], capture_output=True, text=True, timeout=5, check=True)
        return commit, bool(status.stdout.strip())
    except (OSError, subprocess.SubprocessError):
        return "", None


def environment_attrs() -> dict:
    """Package and library versions, git commit and platform, as root attributes."""
    import vcirun

    commit, dirty = git_commit()
    versions = {name: _version(name) for name in ("numpy", "scipy", "numba", "h5py", "sympy", "pydantic",
                                                  "matplotlib")}
    versions["hdf5"] = h5py.version.hdf5_version
    versions["python"] = platform.python_version()
    return {
        "vcirun_version": getattr(vcirun, "__version__", _version("vcirun")),
        "git_commit": commit, "git_dirty": "" if dirty is None else ("yes" if dirty else "no"),
        "python_version": platform.python_version(), "numpy_version": versions["numpy"],
        "scipy_version": versions["scipy"], "numba_version": versions["numba"], "h5py_version": versions["h5py"],
        "hdf5_version": versions["hdf5"], "sympy_version": versions["sympy"], "versions": versions,
        "platform": platform.platform(), "hostname": platform.node(),
    }
