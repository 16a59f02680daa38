"""Files of one run, written by `Trajectory.save(... .h5)` and `vcirun simulate --output run.h5`
(format "vcirun-trajectory", group `trajectory`): recognised and read for `vcirun info`, `plot` and
`animate`, which also take a sweep's results file."""
from __future__ import annotations

from pathlib import Path

from .errors import StorageError, one_line

__all__ = ["TRAJECTORY_FORMAT", "is_trajectory_file", "read_single", "not_read_back"]

TRAJECTORY_FORMAT = "vcirun-trajectory"
# the other formats Trajectory.save writes: for other tools, not read back by vcirun
_EXPORTS = {".nc": "netCDF (xarray.open_dataset)", ".csv": "CSV (pandas.read_csv)", ".npz": "npz (numpy.load)"}


def not_read_back(path) -> str | None:
    """The one-line error for a run saved in a format vcirun writes but does not read back (.nc, .csv,
    .npz), else None: None too for a file that is not there (its own error) and for one of vcirun's
    HDF5 files under such a name (a sweep's results written as .nc is read as any results file)."""
    path = Path(path)
    kind = _EXPORTS.get(path.suffix.lower())
    if kind is None or not path.is_file():
        return None
    try:
        import h5py

        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format", "")
            fmt = fmt.decode() if isinstance(fmt, bytes) else str(fmt)
        if fmt.startswith("vcirun"):
            return None
    except Exception:  # noqa: BLE001 - not HDF5 or unreadable: not one of vcirun's files
        pass
    return (f"{path}: a run saved as {kind} is for other tools; vcirun info, plot and animate read a run "
            "saved as .h5 (vcirun simulate --output run.h5, or Trajectory.save('run.h5'))")


def is_trajectory_file(path) -> bool:
    """True for an HDF5 file written by Trajectory.save (False for anything else, a sweep's file too)."""
    path = Path(path)
    if path.suffix.lower() not in (".h5", ".hdf5") or not path.is_file():
        return False
    import h5py

    from .legacy_text import check_variable_text

    try:
        with h5py.File(path, "r") as f:
            check_variable_text(path, f, "write it again")   # (damaged variable-length text: not one)
            fmt = f.attrs.get("format", "")
            fmt = fmt.decode() if isinstance(fmt, bytes) else str(fmt)
            return fmt == TRAJECTORY_FORMAT and "trajectory" in f
    except Exception:  # noqa: BLE001 - not HDF5, unreadable: not a trajectory file
        return False


def read_single(path):
    """The Trajectory of a one-run file (StorageError naming the file if it cannot be read)."""
    import h5py

    from ..run.trajectory import read_trajectory
    from .legacy_text import check_variable_text

    try:
        # a file of an earlier vcirun holds variable-length text: read in a child with a deadline first
        with h5py.File(path, "r") as f:
            check_variable_text(path, f, "write it again with vcirun simulate --output")
        return read_trajectory(path)
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise StorageError(f"{path}: cannot read the run ({one_line(e)}); write it again with vcirun simulate "
                           "--output") from None
