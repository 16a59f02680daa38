"""Batches: many runs (or references) in one HDF5 group, the unit a sweep stores.

A sweep of thousands of short runs would spend its time creating HDF5 objects if every run were a
group of its own (~17 datasets and ~45 attributes each: 4.6 s of storage against 0.3 s of compute
for the 408 runs of configs/fig4.yaml). A batch holds the items one commit makes durable, with a
fixed number of objects whatever its size:

    /run_batches/<8-digit sequence number>/        (references: /reference_batches/...)
        key     (k,) text     the items' keys (run ids; initial-condition keys)
        attrs   (k,) text     each item's attributes as one JSON object (the encoded attributes of a
                              v1 run group: JSON-valued ones stay JSON text inside it; NaN as NaN)
        (text: fixed-length UTF-8 strings as long as the longest item, NUL-padded; files written
        before that hold variable-length strings, read alike)
        rows    (k, F) i8     rows of array field j held by item i; -1 where the item lacks the field
        crc     (k, F+1) u4   CRC-32 of item i's key and attributes text (column 0) and of its rows of
                              field j (column j + 1, little-endian bytes; 0 where it lacks the field)
        <field> (sum_i rows[i, j], ...)  the items' arrays of that field, concatenated along axis 0
        attributes: fields (JSON list, the column order of rows), scalar_fields (JSON list: fields
                    stored per item as 0-d arrays, kept here as one row each), n_items, complete
                    (written last; a batch without it is ignored)

Item i's array `name` is `data[name][start:start + rows[i, j]]` with start the sum of rows[:i, j]
clipped at 0. The checksums are computed once, when the items are packed in the client (before the
journal record that carries them), and travel with the items into the file, so bit rot anywhere on the
way or at rest shows as an item whose data fail their checksum (`data_problems`); the readers report
it and a resume recomputes it, nothing serves it as data. A batch without `crc` (files written before
it existed) is read unverified. Items of one batch share each field's dtype and trailing shape (`pack` splits
otherwise). Sequence numbers grow with every batch written; where one key appears in several
batches the later one holds the current item. Item paths name an item wherever it is stored:
"runs/<key>" (every copy, and a v1 group of that name) or "<batch path>/<key>" (the copy in one
batch), and are what deletion records and the readers' lists of damaged items carry.
"""
from __future__ import annotations

import json
import zlib
from dataclasses import dataclass

import numpy as np

__all__ = ["BATCH_GROUPS", "ITEM_GROUPS", "Batch", "ItemView", "pack", "write_batch", "read_batch", "checked_batch",
           "batch_names", "next_batch_name", "delete_items", "count_items", "item_path", "split_item_path",
           "jsonable_attr", "attr_from_json", "item_text", "attrs_text", "stamped", "checksums", "data_problems",
           "CHECK_BYTES"]

BATCH_GROUPS = {"run": "run_batches", "reference": "reference_batches"}
ITEM_GROUPS = {"run": "runs", "reference": "references"}   # v1 per-item groups; item paths
_KIND_OF_BATCH_GROUP = {v: k for k, v in BATCH_GROUPS.items()}
_KIND_OF_ITEM_GROUP = {v: k for k, v in ITEM_GROUPS.items()}
NUMERIC_KINDS = "biuf"


def jsonable_attr(v):
    """An encoded attribute as JSON (numeric arrays tagged with their dtype and shape)."""
    if isinstance(v, np.ndarray):
        return {"__ndarray__": v.dtype.str, "shape": list(v.shape), "data": v.ravel().tolist()}
    if isinstance(v, np.generic):
        return v.item()
    return v


def item_text(enc_attrs: dict) -> str:
    """An item's encoded attributes as the JSON text a batch stores (its `attrs` dataset)."""
    return json.dumps({k: jsonable_attr(v) for k, v in enc_attrs.items()}, allow_nan=True)


def attrs_text(attrs: dict) -> str:
    """item_text(group_attrs(attrs)) in one pass: the plain numbers pass as they are (a sweep's workers
    encode every run's ~45 attributes)."""
    from ..run.trajectory_files import JSON_ATTRS, group_attrs

    out = {}
    for k, v in attrs.items():
        t = type(v)
        if (t is float or t is int or t is bool) and k not in JSON_ATTRS and k != "complete":
            out[k] = v
        else:
            enc = group_attrs({k: v})
            if k in enc:
                out[k] = jsonable_attr(enc[k])
    return json.dumps(out, allow_nan=True)


def stamped(text: str, key: str, value) -> str:
    """`text` (an item's JSON object) with one more attribute (a later duplicate key wins in JSON)."""
    extra = json.dumps({key: value})[1:]
    return "{" + extra if text.strip() == "{}" else text.rstrip()[:-1] + ", " + extra


def attr_from_json(v):
    if type(v) is dict and "__ndarray__" in v:
        dt = np.dtype(v["__ndarray__"])
        if dt.kind not in NUMERIC_KINDS:
            raise ValueError("non-numeric array attribute")
        return np.asarray(v["data"], dtype=dt).reshape(v["shape"])
    return v


def item_path(kind: str, key: str) -> str:
    """The path naming every stored copy of an item: runs/<key> or references/<key>."""
    return f"{ITEM_GROUPS[kind]}/{key}"


def split_item_path(path: str):
    """(kind, key, batch group path or None) of an item path; None for the path of a whole batch."""
    head, _, rest = path.partition("/")
    if head in _KIND_OF_ITEM_GROUP:
        return _KIND_OF_ITEM_GROUP[head], rest, None
    if head in _KIND_OF_BATCH_GROUP:
        name, _, key = rest.partition("/")
        if key:
            return _KIND_OF_BATCH_GROUP[head], key, f"{head}/{name}"
    return None


@dataclass
class Batch:
    """Items of one kind in memory: keys, encoded attributes, and their arrays by field."""
    keys: list
    attrs: list                # encoded attributes of each item (vcirun.run.trajectory_files.group_attrs)
    fields: list               # field names, the columns of rows
    scalar: list               # fields held per item as 0-d arrays
    rows: np.ndarray           # (k, F) int64; -1: the item lacks the field
    data: dict                 # field -> concatenated array (or an h5py dataset: sliced on demand)
    texts: list | None = None  # each item's attributes as JSON text where known (then attrs[i] may be None)
    crc: np.ndarray | None = None  # (k, F + 1) uint32 checksums (`checksums`), where known

    def text(self, i: int) -> str:
        t = self.texts[i] if self.texts is not None else None
        return t if t is not None else item_text(self.attrs[i])

    def checksums(self) -> np.ndarray:
        """The (k, F + 1) CRC-32 table (computed from the data in memory the first time)."""
        if self.crc is None:
            self.crc = checksums(self)
        return self.crc

    def __len__(self) -> int:
        return len(self.keys)

    def starts(self) -> np.ndarray:
        """(k + 1, F): where each item's rows of each field begin."""
        out = np.zeros((len(self.keys) + 1, len(self.fields)), dtype=np.int64)
        np.cumsum(np.maximum(self.rows, 0), axis=0, out=out[1:])
        return out

    def arrays(self, i: int, starts=None) -> list:
        """(name, array) pairs of item i, in field order (arrays it lacks are left out)."""
        st = self.starts() if starts is None else starts
        return [(name, self.field(i, name, st)) for j, name in enumerate(self.fields) if self.rows[i, j] >= 0]

    def shape_of(self, i: int, name: str):
        """Shape of item i's array `name` (None if it lacks it), from the row table alone."""
        tails = self.__dict__.get("_tails")
        if tails is None:   # (an h5py dataset's shape costs ~10 us a call: read once per batch)
            tails = self._tails = {n: (None if n in self.scalar else tuple(self.data[n].shape[1:]))
                                   for n in self.fields}
            self._col = {n: j for j, n in enumerate(self.fields)}
        j = self._col.get(name)
        if j is None:
            return None
        r = int(self.rows[i, j])
        if r < 0:
            return None
        tail = tails[name]
        return () if tail is None else (r,) + tail

    def field(self, i: int, name: str, starts=None):
        """Item i's array `name` (KeyError if it lacks it)."""
        j = self.fields.index(name) if name in self.fields else -1
        if j < 0 or int(self.rows[i, j]) < 0:
            raise KeyError(name)
        st = self.starts() if starts is None else starts
        a = np.asarray(self.data[name][st[i, j]:st[i, j] + int(self.rows[i, j])])
        return a.reshape(()) if name in self.scalar else a

    def view(self, i: int, starts=None) -> "ItemView":
        return ItemView(self, i, self.starts() if starts is None else starts)

    def select(self, keep) -> "Batch":
        """The items at the positions `keep` (data loaded)."""
        keep = [int(i) for i in keep]
        st = self.starts()
        data = {}
        for j, name in enumerate(self.fields):
            parts = [np.asarray(self.data[name][st[i, j]:st[i, j] + max(int(self.rows[i, j]), 0)]) for i in keep]
            tail = tuple(self.data[name].shape[1:])
            data[name] = np.concatenate(parts) if parts else np.zeros((0,) + tail, self.data[name].dtype)
        return Batch([self.keys[i] for i in keep], [self.attrs[i] for i in keep], list(self.fields),
                     list(self.scalar), self.rows[keep].reshape(len(keep), len(self.fields)), data,
                     None if self.texts is None else [self.texts[i] for i in keep],
                     None if self.crc is None else self.crc[keep].reshape(len(keep), len(self.fields) + 1))


class ItemView:
    """Item i of a batch seen like an h5py group: `attrs` (encoded), `name in v`, `v[name]` (read on
    demand), `shape_of(name)` from the row table (what vcirun.io.checks and trajectory_from_group use)."""

    def __init__(self, batch: Batch, i: int, starts):
        self.batch, self.i, self._starts = batch, i, starts
        self.attrs = batch.attrs[i]

    def shape_of(self, name: str):
        return self.batch.shape_of(self.i, name)

    def __contains__(self, name) -> bool:
        return self.shape_of(name) is not None

    def __getitem__(self, name):
        return self.batch.field(self.i, name, self._starts)

    def get(self, name, default=None):
        return self[name] if name in self else default

    def __iter__(self):
        return iter([n for n in self.batch.fields if n in self])


_TABLE = ("key", "attrs", "rows", "crc")   # a batch's own datasets
CHECK_BYTES = 32 * 2**20   # verification reads a field in slabs of whole items of about this size


def _text_crc(key: str, text: str) -> int:
    return zlib.crc32(text.encode("utf-8", "surrogatepass"), zlib.crc32(key.encode("utf-8", "surrogatepass") + b"\0"))


def _le(a: np.ndarray) -> np.ndarray:
    """`a` as C-contiguous little-endian data (the bytes a checksum covers on any machine)."""
    return np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<") if a.dtype.byteorder not in "|<" else a.dtype)


def _row_crcs(a: np.ndarray, counts) -> list:
    """CRC-32 of consecutive runs of `counts` rows of the array `a` (in memory)."""
    b = memoryview(_le(a)).cast("B") if a.size else memoryview(b"")
    per_row = a.dtype.itemsize * int(np.prod(a.shape[1:], dtype=np.int64)) if a.ndim else a.dtype.itemsize
    out, off = [], 0
    for r in counts:
        n = int(r) * per_row
        out.append(zlib.crc32(b[off:off + n]))
        off += n
    return out


def checksums(batch: Batch) -> np.ndarray:
    """(k, F + 1) uint32: CRC-32 of each item's key and attributes text, and of its rows of each field."""
    k, F = len(batch.keys), len(batch.fields)
    out = np.zeros((k, F + 1), dtype=np.uint32)
    for i in range(k):
        out[i, 0] = _text_crc(str(batch.keys[i]), batch.text(i))
    for j, name in enumerate(batch.fields):
        rows = batch.rows[:, j]
        crcs = _row_crcs(np.asarray(batch.data[name]), np.maximum(rows, 0))
        out[:, j + 1] = np.where(rows >= 0, np.asarray(crcs, dtype=np.uint32), 0)
    return out


def data_problems(batch: Batch, items=None) -> dict:
    """{item index: why its stored data cannot be trusted} for the items `items` (default all) of a
    batch read with `read_batch`: a key, attributes text or field whose CRC-32 differs from the table's
    (bit rot, a damaged block, an edit), or data HDF5 cannot read. {} for a batch without checksums
    (written before they existed). Reads each field once, in slabs of about CHECK_BYTES of whole items."""
    if batch.crc is None:
        return {}
    k, F = len(batch.keys), len(batch.fields)
    want = range(k) if items is None else sorted(set(int(i) for i in items))
    if batch.crc.shape != (k, F + 1):
        return {i: f"checksum table has shape {batch.crc.shape}, expected {(k, F + 1)}" for i in want}
    out = {}
    for i in want:
        if _text_crc(str(batch.keys[i]), batch.text(i)) != int(batch.crc[i, 0]):
            out[i] = "key or attributes fail their checksum (the stored text changed since it was written)"
    starts = batch.starts()
    for j, name in enumerate(batch.fields):
        d = batch.data[name]
        per_row = max(1, d.dtype.itemsize * int(np.prod(d.shape[1:], dtype=np.int64)))
        slab: list = []
        for i in [*want, None]:
            if i is not None and batch.rows[i, j] < 0:
                continue
            if slab and (i is None or i != slab[-1] + 1 or
                         (starts[i + 1, j] - starts[slab[0], j]) * per_row > CHECK_BYTES):
                a0, a1 = int(starts[slab[0], j]), int(starts[slab[-1] + 1, j])
                try:
                    a = np.asarray(d[a0:a1])
                except Exception as e:  # noqa: BLE001 - HDF5 cannot read the blocks
                    for t in slab:
                        out.setdefault(t, f"dataset {name} unreadable ({type(e).__name__})")
                else:
                    for t, c in zip(slab, _row_crcs(a, [batch.rows[t, j] for t in slab])):
                        if c != int(batch.crc[t, j + 1]):
                            out.setdefault(t, f"dataset {name} fails its checksum (the stored data changed since "
                                              "they were written)")
                slab = []
            if i is not None:
                slab.append(i)
    return out


def pack(items) -> list:
    """Batches of (key, encoded attributes, arrays[, JSON text of the attributes]) items, arrays as a
    mapping or (name, array) pairs; numeric arrays only. Items go to the first batch whose fields
    agree with theirs in dtype and trailing shape (one batch for the runs of one sweep)."""
    by_sig: dict = {}   # items grouped by their exact signature first (the common case: a few kinds)
    for key, attrs, arrays, *text in items:
        arr = {}
        for name, v in (arrays.items() if isinstance(arrays, dict) else arrays):
            if name in _TABLE:
                raise ValueError(f"batch item {key!r}: an array may not be named {name!r} (a batch's own dataset)")
            a = v if isinstance(v, np.ndarray) else np.asarray(v)
            if a.dtype.kind not in NUMERIC_KINDS:
                a = a.astype(float)
            arr[name] = a
        sig = tuple((name, a.dtype.str, a.shape[1:] if a.ndim else "scalar") for name, a in arr.items())
        by_sig.setdefault(sig, []).append((str(key), attrs, arr, text[0] if text else None))
    groups = []   # [fields' (dtype, trailing shape), [item, ...]]
    for sig, its in by_sig.items():
        fields = {name: (dt, tail) for name, dt, tail in sig}
        for g in groups:
            if all(g[0].get(n, s) == s for n, s in fields.items()):
                g[0].update(fields)
                g[1].extend(its)
                break
        else:
            groups.append([fields, list(its)])
    out = []
    for sig, its in groups:
        fields = list(sig)
        scalar = [n for n in fields if sig[n][1] == "scalar"]
        rows = np.full((len(its), len(fields)), -1, dtype=np.int64)
        data = {}
        for j, name in enumerate(fields):
            parts = []
            for i, (_, _, arr, _) in enumerate(its):
                a = arr.get(name)
                if a is None:
                    continue
                a = a.reshape(1) if name in scalar else a
                rows[i, j] = a.shape[0]
                parts.append(a)
            data[name] = np.ascontiguousarray(np.concatenate(parts)) if len(parts) > 1 else \
                np.ascontiguousarray(parts[0])
        texts = [t for *_, t in its]
        out.append(Batch([it[0] for it in its], [it[1] for it in its], fields, scalar, rows, data,
                         texts if any(t is not None for t in texts) else None))
    return out


# --- HDF5 ------------------------------------------------------------------------------------------------
def batch_names(f, kind: str) -> list:
    """Names of the batch groups of `kind` in the open file, in sequence order."""
    group = BATCH_GROUPS[kind]
    if group not in f:
        return []
    return sorted(f[group].keys())


def next_batch_name(f, kind: str) -> str:
    names = [n for n in batch_names(f, kind) if n.isdigit()]
    return f"{(int(max(names)) + 1 if names else 1):08d}"


def write_batch(f, kind: str, batch: Batch, name: str | None = None) -> str:
    """Write `batch` as a new group of the open file (the next sequence number unless `name` is given);
    returns its path. `complete` is written last."""
    from ..run.trajectory_files import fixed_texts, write_encoded

    group = BATCH_GROUPS[kind]
    name = name or next_batch_name(f, kind)
    path = f"{group}/{name}"
    arrays = [("rows", batch.rows), ("crc", batch.checksums())] + [(n, batch.data[n]) for n in batch.fields]
    meta = {"fields": json.dumps(batch.fields), "scalar_fields": json.dumps(batch.scalar),
            "n_items": len(batch.keys), "kind": kind}
    # the text datasets first; write_encoded writes the numeric ones and the attributes, `complete` last
    f.require_group(group)
    if path in f:
        del f[path]
    g = f.create_group(path)
    g.create_dataset("key", data=fixed_texts(batch.keys))
    g.create_dataset("attrs", data=fixed_texts([batch.text(i) for i in range(len(batch.keys))]))
    write_encoded(f, path, meta, arrays, group=g)
    return path


def read_batch(g, data: bool = False) -> Batch:
    """The Batch of an open batch group (arrays as h5py datasets, sliced on demand; `data`: loaded)."""
    from ..run.trajectory_files import decode_attr

    fields = decode_attr("fields", g.attrs.get("fields", "[]"))
    fields = json.loads(fields) if isinstance(fields, str) else list(fields)
    scalar = decode_attr("scalar_fields", g.attrs.get("scalar_fields", "[]"))
    scalar = json.loads(scalar) if isinstance(scalar, str) else list(scalar)
    keys = batch_keys(g)
    texts = [str(t) for t in g["attrs"].asstr(errors="replace")[()]]
    attrs = [_item_attrs(t) for t in texts]
    rows = np.asarray(g["rows"][()], dtype=np.int64)
    crc = np.asarray(g["crc"][()], dtype=np.uint32) if "crc" in g else None
    arrays = {n: (g[n][()] if data else g[n]) for n in fields}
    return Batch(keys, attrs, fields, scalar, rows.reshape(len(keys), len(fields)), arrays, texts, crc)


def batch_keys(g) -> list:
    """The keys of an open batch group, as str. Bytes that are not UTF-8 (damage) read as U+FFFD, so
    that the damaged key alone fails its checksum, not the whole batch (a text that passes it is the
    text written, whatever the decoding did)."""
    return [str(k) for k in g["key"].asstr(errors="replace")[()]]


def _item_attrs(text: str) -> dict:
    """An item's attributes from its JSON text; {} where the text is not a JSON object (damage: the item
    then fails its checksum and its check, and the batch's other items stay readable)."""
    try:
        d = json.loads(text)
        return {k: attr_from_json(v) for k, v in d.items()} if type(d) is dict else {}
    except (ValueError, TypeError, AttributeError):
        return {}


def checked_batch(g):
    """(Batch, None) of a batch group marked complete whose table agrees with its datasets, else
    (None, why it cannot be trusted); the items' own checks are vcirun.io.checks.run_problem /
    reference_problem."""
    try:
        b = read_batch(g)
    except Exception as e:  # noqa: BLE001 - missing datasets, unreadable attributes or text
        return None, f"batch table unreadable ({type(e).__name__}: {' '.join(str(e).split())[:120]})"
    k = len(b.keys)
    if len(b.attrs) != k or b.rows.shape != (k, len(b.fields)):
        return None, f"batch table inconsistent ({k} keys, {len(b.attrs)} attribute sets, rows {b.rows.shape})"
    if len(set(b.keys)) != k:
        return None, "batch holds a key twice"
    for j, name in enumerate(b.fields):
        d = b.data[name]
        if not hasattr(d, "dtype") or d.dtype.kind not in NUMERIC_KINDS:
            return None, f"dataset {name} is not numeric"
        want = int(np.maximum(b.rows[:, j], 0).sum())
        if len(d.shape) < 1 or d.shape[0] != want:
            return None, f"dataset {name} has {d.shape[0] if d.shape else 0} rows, the table {want}"
    return b, None


def delete_items(f, paths) -> None:
    """Delete items from the open file: item paths (every copy: "runs/<key>", a v1 group of that name
    included), the copy in one batch ("run_batches/<name>/<key>") or whole batches
    ("run_batches/<name>"). A batch that loses items is rewritten under its name with the rest."""
    every = {"run": set(), "reference": set()}
    one = {}
    for p in paths:
        s = split_item_path(p)
        if s is None:
            if p in f:
                del f[p]
            continue
        kind, key, batch = s
        if batch is None:
            every[kind].add(key)
            if p in f:
                del f[p]          # a v1 group
        else:
            one.setdefault(batch, set()).add(key)
    for kind in BATCH_GROUPS:
        for name in batch_names(f, kind):
            path = f"{BATCH_GROUPS[kind]}/{name}"
            drop = every[kind] | one.get(path, set())
            if not drop:
                continue
            g = f[path]
            try:
                keys = batch_keys(g)
            except Exception:  # noqa: BLE001 - a damaged batch: the readers ignore it already
                continue
            if not drop.intersection(keys):
                continue
            b = read_batch(g, data=True)
            keep = [i for i, k in enumerate(b.keys) if k not in drop]
            rest = b.select(keep) if keep else None
            del f[path]
            if rest is not None:
                write_batch(f, kind, rest, name=name)


def count_items(f, kind: str) -> int:
    """Items of `kind` the open file holds (v1 groups and batches; a key held twice counts once)."""
    keys = set(f[ITEM_GROUPS[kind]].keys()) if ITEM_GROUPS[kind] in f else set()
    for name in batch_names(f, kind):
        g = f[f"{BATCH_GROUPS[kind]}/{name}"]
        if bool(g.attrs.get("complete", False)) and "key" in g:
            keys.update(batch_keys(g))
    return len(keys)
