"""Variable-length text in results files written before vcirun stored every string fixed-length.

Variable-length strings live in the file's global heap. Reading one whose heap collection is damaged
(zeroed or flipped bytes there) can make libhdf5 loop in C without ever returning, where no Python
code, signal handler or timeout can stop it. vcirun writes text fixed-length only (vcirun.run.
trajectory_files.fixed_text), so its files have no such object and are read directly. A file that
holds variable-length text where vcirun's readers look (root attributes, the attributes of run and
reference groups and batches, a batch's `key` and `attrs` datasets, a one-run file's `trajectory`
group) is read once first in a child process with a deadline (`check_variable_text`): if the child
does not finish within PROBE_SECONDS, or dies, the file is reported damaged in one line and the
readers do not touch it. Finding out costs the object headers only (types, never values; for a sweep
file marked by its writer, the root attributes only); the child runs only for such files, once per
file version per process. A writer that resumes such a file rewrites its text fixed-length
(`fix_variable_text`) and marks it.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from .errors import StorageError

__all__ = ["PROBE_SECONDS", "MARK", "MARK_VALUE", "has_variable_text", "check_variable_text", "fix_variable_text"]

PROBE_SECONDS = 30.0   # what a child may take to read every text a reader reads (a healthy file: well under 1 s)
_CONTAINERS = ("run_batches", "reference_batches", "runs", "references")
_TEXT_DATASETS = ("key", "attrs")
# the root attribute a sweep file's writer sets on every rewrite, after `fix_variable_text`: every text
# of the file is fixed-length (a resumed file of an earlier vcirun included)
MARK, MARK_VALUE = "text_storage", "fixed-length"
_SEEN: dict = {}       # (path, device, inode, size, mtime) -> None (read in time) or the StorageError text


def _variable(tid) -> bool:
    from h5py import h5t

    c = tid.get_class()
    return c == h5t.VLEN or (c == h5t.STRING and tid.is_variable_str())


def _attr_ids(oid):
    from h5py import h5, h5a

    order = h5.INDEX_CRT_ORDER if oid.get_create_plist().get_attr_creation_order() else h5.INDEX_NAME
    for i in range(h5a.get_num_attrs(oid)):
        yield h5a.open(oid, index=i, index_type=order)


def _objects(f):
    """The groups a reader reads attributes of, and the text datasets it reads: (kind, object id,
    the h5py group or dataset)."""
    import h5py

    yield "group", f.id, f
    if "trajectory" in f and isinstance(f["trajectory"], h5py.Group):
        yield "group", f["trajectory"].id, f["trajectory"]
    for top in _CONTAINERS:
        if top not in f or not isinstance(f[top], h5py.Group):
            continue
        for name in f[top]:
            g = f[top].get(name)
            if not isinstance(g, h5py.Group):
                continue
            yield "group", g.id, g
            for d in _TEXT_DATASETS:
                ds = g.get(d)
                if isinstance(ds, h5py.Dataset):
                    yield "dataset", ds.id, ds


def has_variable_text(f) -> bool:
    """Whether the open file holds variable-length text where vcirun's readers look (read from the
    object headers: types, not values). A sweep file whose root attribute MARK says its writer stored
    every text fixed-length costs its root attributes only; others are walked. True also when the
    headers cannot be walked (damaged): the child then finds out."""
    try:
        if any(_variable(a.get_type()) for a in _attr_ids(f.id)):
            return True
        if _marked(f):
            return False
        for kind, oid, _ in _objects(f):
            if kind == "dataset":
                if _variable(oid.get_type()):
                    return True
            elif any(_variable(a.get_type()) for a in _attr_ids(oid)):
                return True
    except Exception:  # noqa: BLE001 - damaged headers: cannot tell
        return True
    return False


def _marked(f) -> bool:
    from h5py import h5a

    if not h5a.exists(f.id, MARK.encode()):
        return False
    v = f.attrs[MARK]
    return isinstance(v, bytes) and v.decode("utf-8", "replace") == MARK_VALUE


def _read_all(path: str) -> None:
    """What the child does: read every attribute value and text dataset `_objects` names."""
    import h5py

    with h5py.File(path, "r") as f:
        for kind, oid, obj in _objects(f):
            try:
                if kind == "dataset":
                    obj[()]
                else:
                    for a in _attr_ids(oid):
                        obj.attrs[a.name.decode("utf-8", "replace")]
            except Exception:  # noqa: BLE001 - an error is the readers' to report; only not returning matters
                pass


def fix_variable_text(f) -> int:
    """Rewrite, in the open file `f` (a writer's copy of a file whose text was read in time), every
    variable-length text `_objects` names as fixed-length, the same text (the checksums cover the text,
    not its storage); returns how many objects changed. A resumed file of an earlier vcirun thus holds
    no variable-length text after its first rewrite, and is read without the child from then on."""
    import h5py

    from ..run.trajectory_files import fixed_texts, storable, text_of

    changed = 0
    for kind, oid, obj in list(_objects(f)):
        if kind == "dataset":
            if _variable(oid.get_type()):
                parent, name = obj.parent, obj.name.rpartition("/")[2]
                texts = [text_of(v) for v in obj[()].ravel()]
                shape = obj.shape
                del parent[name]
                parent.create_dataset(name, data=fixed_texts(texts).reshape(shape))
                changed += 1
            continue
        names = [a.name.decode("utf-8", "replace") for a in _attr_ids(oid) if _variable(a.get_type())
                 and a.get_type().get_class() == h5py.h5t.STRING]
        for name in names:
            v = obj.attrs[name]
            value = storable(text_of(v)) if np.ndim(v) == 0 else \
                fixed_texts([text_of(x) for x in np.ravel(v)]).reshape(np.shape(v))
            del obj.attrs[name]
            obj.attrs[name] = value
            changed += 1
    return changed


def _stamp(path: Path):
    st = path.stat()
    return (str(path.resolve()), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def check_variable_text(path, f, fix: str) -> None:
    """StorageError (ending with `fix`) if the open file `f` at `path` holds variable-length text that
    libhdf5 does not finish reading within PROBE_SECONDS in a child process, or that kills the child;
    nothing for files without variable-length text (every file vcirun writes) or that passed before."""
    path = Path(path)
    try:
        stamp = _stamp(path)
    except OSError:
        stamp = None
    if stamp is not None and stamp in _SEEN:
        if _SEEN[stamp] is not None:
            raise StorageError(_SEEN[stamp])
        return
    if not has_variable_text(f):
        return
    try:
        _probe(path, fix)
    except StorageError as e:
        if stamp is not None:
            _SEEN[stamp] = str(e)
        raise
    if stamp is not None:
        _SEEN[stamp] = None


def _probe(path: Path, fix: str) -> None:
    pkg_parent = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([pkg_parent, *filter(None, [os.environ.get("PYTHONPATH")])])}
    code = "import sys; from vcirun.io.legacy_text import _read_all; _read_all(sys.argv[1])"
    try:
        r = subprocess.run([sys.executable, "-c", code, str(path)], timeout=PROBE_SECONDS, env=env,
                           stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    except subprocess.TimeoutExpired:
        raise StorageError(f"{path}: damaged results file (its variable-length text, written by an earlier vcirun, "
                           f"was not read within {PROBE_SECONDS:g} s: libhdf5 loops on a damaged global heap); "
                           f"{fix}") from None
    except OSError as e:
        raise StorageError(f"{path}: cannot check the file's variable-length text in a child process ({e}); "
                           f"{fix}") from None
    if r.returncode < 0:
        raise StorageError(f"{path}: damaged results file (reading its variable-length text, written by an earlier "
                           f"vcirun, killed the reading process with signal {-r.returncode}); {fix}")
    if r.returncode != 0:
        tail = " ".join(r.stderr.decode("utf-8", "replace").split())[-200:]
        raise StorageError(f"{path}: cannot check the file's variable-length text in a child process "
                           f"(exit {r.returncode}: {tail}); {fix}")
