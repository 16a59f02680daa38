"""The journal beside a results file (`.NAME.journal`): the binary record format, reading it back, and
applying it to the HDF5 file or to a reader's view of it.

A record is b"VJR1", a u64 payload length, a u32 CRC-32 of the payload, then the payload: a u32 header
length, the header (JSON: kind, key, encoded attributes, array table) and the arrays' bytes. Arrays are
numeric only (dtype kinds b/i/u/f), so reading a journal never unpickles anything. The first record is
"open" (the session's random token and the config key); then "batch" records (the runs or references
of one commit, vcirun.io.batches: key "run" or "reference", the items' keys and row table in the
header; their attributes' JSON texts and the concatenated arrays as blobs), "delete" (an item path
or a batch group) and
"session" (the history so far); every record after the open one carries the session's token too.
Journals of schema 1 hold one "run" or "reference" record per item; they are read and applied the
same way.

A kill in the middle of an append leaves a torn tail (a last record shorter than its length field):
everything before it is committed. A damaged record (a flipped byte, a bad block) is skipped, not
taken for the end: `read_journal` looks for the next record that starts with the magic and passes its
CRC and reads on from there; a last record whole by its length but failing its CRC is damage too.
`Journal.skipped` counts the damaged stretches and `skipped_bytes` their size, and the readers say so
(the runs a skipped record held are missing, and a resume recomputes them). A damaged open record
loses only the token, which the next intact record carries.

The file names the journal that extends it (root attribute `journal` = the token of its open record)
and how much of it the file holds already (`journal_applied`, a byte offset); `file_journal` returns
the records past that offset of the journal the file names, and None for a stale journal.
"""
from __future__ import annotations

import json
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..run.trajectory_files import decode_attr, decode_attrs
from .batches import Batch, attr_from_json, delete_items, jsonable_attr, pack, split_item_path, write_batch
from .checks import NUMERIC_KINDS
from .errors import StorageError, os_text, write_error

__all__ = ["journal_path", "record_pieces", "batch_pieces", "write_all", "JournalRecord", "Journal",
           "read_journal", "overlay", "MemGroup", "applied", "file_journal", "apply_journal"]

_MAGIC = b"VJR1"
_REC = struct.Struct("<4sQI")
_HDR = struct.Struct("<I")
_MAX_HEADER = 64 * 2**20


def journal_path(path) -> Path:
    """The journal beside the results file; for a symlink, beside its target (where the writer writes)."""
    p = Path(os.path.realpath(path))
    return p.with_name(f".{p.name}.journal")


def record_pieces(kind: str, key: str, enc_attrs: dict | None = None, arrays=(), extra: dict | None = None):
    """(list of byte pieces, total length) of one record; array bytes are not copied."""
    table, blobs, off = [], [], 0
    for name, value in arrays:
        a = np.ascontiguousarray(value)
        if a.dtype.kind not in NUMERIC_KINDS:
            a = a.astype(float)
        mv = memoryview(a).cast("B") if a.size else memoryview(b"")
        table.append([name, a.dtype.str, list(a.shape), off, mv.nbytes])
        blobs.append(mv)
        off += mv.nbytes
    header = {"kind": kind, "key": key, "arrays": table, **(extra or {})}
    if enc_attrs is not None:
        header["attrs"] = {k: jsonable_attr(v) for k, v in enc_attrs.items()}
    hb = json.dumps(header, allow_nan=True).encode()
    payload = [_HDR.pack(len(hb)), hb, *blobs]
    crc = 0
    for piece in payload:
        crc = zlib.crc32(piece, crc)
    length = _HDR.size + len(hb) + off
    return [_REC.pack(_MAGIC, length, crc), *payload], _REC.size + length


def batch_pieces(kind: str, batch: Batch, token: str = ""):
    """(pieces, length) of the record of one batch of `kind` ("run" | "reference"): the row table and
    the items' checksums in the header, the items' JSON texts (made by the workers where they can) as
    one UTF-8 blob with their end offsets, kept verbatim to the HDF5 batch, and the fields' arrays."""
    texts = [batch.text(i).encode("utf-8", "surrogatepass") for i in range(len(batch.keys))]
    ends = np.cumsum([len(t) for t in texts], dtype=np.int64) if texts else np.zeros(0, np.int64)
    extra = {"keys": list(batch.keys), "fields": list(batch.fields), "scalar": list(batch.scalar),
             "rows": batch.rows.tolist(), "crc": batch.checksums().tolist(), **({"token": token} if token else {})}
    arrays = [(_TEXTS, np.frombuffer(b"".join(texts), dtype=np.uint8)), (_TEXT_ENDS, ends)]
    return record_pieces("batch", kind, None, arrays + [(n, batch.data[n]) for n in batch.fields], extra=extra)


_TEXTS, _TEXT_ENDS = "\x00texts", "\x00text_ends"   # a batch record's item texts (no field has such a name)


class _LazyAttrs(list):
    """The items' encoded attributes of a batch read from the journal, parsed from their texts when
    first asked for (writing the batch to the HDF5 file needs the texts only)."""

    def __init__(self, texts):
        super().__init__([None] * len(texts))
        self._texts, self._parsed = texts, False

    def _parse(self):
        if not self._parsed:
            self._parsed = True
            for i, t in enumerate(self._texts):
                list.__setitem__(self, i, {k: attr_from_json(v) for k, v in json.loads(t).items()})

    def __getitem__(self, i):
        self._parse()
        return list.__getitem__(self, i)

    def __iter__(self):
        self._parse()
        return list.__iter__(self)


def write_all(fd: int, pieces) -> None:
    """Write every byte of `pieces` to the descriptor `fd` (os.write may write less than asked)."""
    for piece in pieces:
        mv = memoryview(piece)
        while mv.nbytes:
            n = os.write(fd, mv)
            mv = mv[n:]


@dataclass
class JournalRecord:
    kind: str              # "batch" | "delete" | "session" (and "run" | "reference" of schema 1)
    key: str
    header: dict
    blob_offset: int       # where the arrays start in the journal file
    end: int               # offset just past this record

    def attrs(self) -> dict:
        return {k: attr_from_json(v) for k, v in (self.header.get("attrs") or {}).items()}

    def item_texts(self, fh) -> list:
        """A batch record's items' attributes as the JSON texts the batch stores (read from `fh`)."""
        (_, blob), (_, ends) = self.arrays(fh, (_TEXTS, _TEXT_ENDS))
        keys = self.header.get("keys") or []
        if len(ends) != len(keys) or (len(ends) and int(ends[-1]) != blob.size):
            raise ValueError("journal batch: its item texts do not match its keys")
        raw = blob.tobytes()
        starts = np.concatenate([[0], ends[:-1]]).astype(int) if len(ends) else []
        return [raw[a:int(b)].decode("utf-8", "surrogatepass") for a, b in zip(starts, ends)]

    def item_attrs(self, fh) -> list:
        """The encoded attributes of a batch record's items."""
        return [{k: attr_from_json(v) for k, v in json.loads(t).items()} for t in self.item_texts(fh)]

    def batch(self, fh) -> Batch:
        """A batch record's Batch (arrays read from the open journal file `fh`, the items' texts kept
        verbatim, their attributes parsed when asked); a schema-1 run or reference record as a batch
        of one."""
        if self.kind != "batch":
            return pack([(self.key, self.attrs(), self.arrays(fh))])[0]
        keys = [str(k) for k in self.header.get("keys") or []]
        fields = [str(n) for n in self.header.get("fields") or []]
        rows = np.asarray(self.header.get("rows") or [], dtype=np.int64).reshape(len(keys), len(fields))
        data = dict(self.arrays(fh, fields))
        if set(data) != set(fields):
            raise ValueError("journal batch: its table does not match its arrays")
        texts = self.item_texts(fh)
        crc = self.header.get("crc")   # the items' checksums, made when they were packed (vcirun.io.batches)
        crc = None if crc is None else np.asarray(crc, dtype=np.uint32).reshape(len(keys), len(fields) + 1)
        return Batch(keys, _LazyAttrs(texts), fields, [str(n) for n in self.header.get("scalar") or []], rows, data,
                     texts, crc)

    @property
    def item_kind(self) -> str:
        """"run" or "reference" for records that carry items."""
        return self.key if self.kind == "batch" else self.kind

    def arrays(self, fh, names=None) -> list:
        """(name, array) pairs (those of `names` only, in that order, when given), read from the open
        journal file `fh`."""
        out = []
        table = self.header.get("arrays", [])
        if names is not None:
            by = {row[0]: row for row in table}
            missing = [n for n in names if n not in by]
            if missing:
                raise ValueError(f"journal record: no array {missing[0]!r}")
            table = [by[n] for n in names]
        for name, dtype, shape, off, nbytes in table:
            dt = np.dtype(dtype)
            if dt.kind not in NUMERIC_KINDS:
                raise ValueError(f"journal array {name}: non-numeric dtype {dtype}")
            fh.seek(self.blob_offset + off)
            buf = fh.read(nbytes)
            if len(buf) != nbytes:
                raise ValueError(f"journal array {name}: truncated")
            out.append((name, np.frombuffer(buf, dtype=dt).reshape(shape).copy()))
        return out


@dataclass
class Journal:
    path: Path
    token: str = ""
    config_key: str | None = ""  # None: its open record was damaged (the token came from a later record)
    records: list = field(default_factory=list)  # after the "open" record, in order
    good_end: int = 0     # offset past the last complete record
    torn: bool = False    # bytes after good_end (a kill or a disk-full in the middle of an append)
    applied: int = 0      # records ending at or before this offset are in the file already (see `after`)
    skipped: int = 0      # damaged stretches between intact records (each one record or more)
    skipped_bytes: int = 0
    damage: list = field(default_factory=list)  # (start, end) offsets of each skipped stretch

    def after(self, offset: int) -> "Journal":
        """The records the file does not hold yet: those ending past `offset` (its `journal_applied`);
        damage the file holds already (before `offset`) is no longer counted."""
        if not offset:
            return self
        damage = [(a, b) for a, b in self.damage if b > offset]
        return Journal(self.path, self.token, self.config_key, [r for r in self.records if r.end > offset],
                       self.good_end, self.torn, max(self.applied, int(offset)), len(damage),
                       sum(b - max(a, int(offset)) for a, b in damage), damage)

    def skipped_text(self) -> str:
        """'' when nothing was skipped, else the sentence the readers print."""
        if not self.skipped:
            return ""
        return (f"{self.skipped} damaged record{'s' * (self.skipped > 1)} ({self.skipped_bytes:,} bytes) in the "
                f"journal {self.path.name} skipped; the runs they held are missing (a resume recomputes them)")

    @property
    def new_bytes(self) -> int:
        return max(0, self.good_end - self.applied)


def read_journal(path) -> Journal | None:
    """The intact records of a journal file (None if there is none or it is not one of ours). A record
    that is truncated or fails its CRC is skipped when an intact record follows it (see the module
    docstring: `skipped`), else it is the torn tail, where reading stops."""
    jp = Path(path)
    try:
        fh = open(jp, "rb")
    except FileNotFoundError:
        return None
    except OSError as e:
        raise StorageError(f"{jp}: cannot read the journal ({os_text(e)})") from None
    with fh:
        size = os.fstat(fh.fileno()).st_size
        j = Journal(jp)
        pos, first = 0, True
        while pos + _REC.size <= size:
            rec = _record_at(fh, pos, size)
            if rec is None:
                nxt = _next_record(fh, pos + 1, size)
                if nxt is None and _whole_record(fh, pos, size):
                    nxt = size     # a last record whole in length but failing its CRC: damage, not a kill
                if nxt is None:
                    break          # the torn tail
                j.skipped += 1
                j.skipped_bytes += nxt - pos
                j.damage.append((pos, nxt))
                pos, first = nxt, False
                continue
            header, blob_offset, end = rec
            kind, key = str(header["kind"]), str(header.get("key", ""))
            if first and kind != "open":
                return None        # not a journal of ours
            first = False
            if kind == "open":
                if j.token:
                    break          # a second open record: not a journal this module wrote
                j.token, j.config_key = str(header.get("token", "")), str(header.get("config_key", ""))
            else:
                if not j.token and header.get("token"):   # the open record was damaged
                    j.token, j.config_key = str(header["token"]), None
                j.records.append(JournalRecord(kind, key, header, blob_offset, end))
            j.good_end = end
            pos = end
        if not j.token:
            return None
        j.torn = pos < size
        return j


def _record_at(fh, pos: int, size: int):
    """(header, blob offset, end) of the intact record at `pos`, or None (truncated, failing its CRC,
    or not a record)."""
    fh.seek(pos)
    magic, length, crc = _REC.unpack(fh.read(_REC.size))
    if magic != _MAGIC or pos + _REC.size + length > size or length < _HDR.size:
        return None
    (hlen,) = _HDR.unpack(fh.read(_HDR.size))
    if hlen > min(length - _HDR.size, _MAX_HEADER):
        return None
    hb = fh.read(hlen)
    c = zlib.crc32(_HDR.pack(hlen))
    c = zlib.crc32(hb, c)
    remaining = length - _HDR.size - hlen
    blob_offset = fh.tell()
    while remaining > 0:
        chunk = fh.read(min(remaining, 1 << 20))
        if not chunk:
            break
        c = zlib.crc32(chunk, c)
        remaining -= len(chunk)
    if remaining or c != crc:
        return None
    try:
        header = json.loads(hb)
        str(header["kind"])
    except (ValueError, KeyError, TypeError):
        return None
    if not isinstance(header, dict):
        return None
    return header, blob_offset, pos + _REC.size + length


def _whole_record(fh, pos: int, size: int) -> bool:
    """Whether the bytes from `pos` to the end are one record by its length field (a kill leaves a
    record shorter than its length: an append is one write of the whole record)."""
    fh.seek(pos)
    head = fh.read(_REC.size)
    if len(head) < _REC.size:
        return False
    _, length, _ = _REC.unpack(head)
    return pos + _REC.size + length == size


def _next_record(fh, start: int, size: int) -> int | None:
    """The offset of the first intact record at or after `start` (None: none, the rest is a torn
    tail). Scans for the magic in blocks; a false match inside a payload fails its CRC."""
    block = 1 << 20
    pos = start
    while pos + _REC.size <= size:
        fh.seek(pos)
        buf = fh.read(block + len(_MAGIC) - 1)
        i = buf.find(_MAGIC)
        while i >= 0:
            if _record_at(fh, pos + i, size) is not None:
                return pos + i
            i = buf.find(_MAGIC, i + 1)
        pos += block
    return None


def applied(f) -> int:
    """How much of its journal the open results file `f` holds already (a background compaction's
    progress): its `journal_applied` offset."""
    v = decode_attr("journal_applied", f.attrs.get("journal_applied", 0))
    return int(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 else 0


def file_journal(path, f) -> Journal | None:
    """The records of the journal that extends the open results file `f` at `path` and that the file
    does not hold yet (a killed session's committed runs), or None (no journal, or a stale one: another
    token or config key). StorageError if the journal exists but cannot be read."""
    expected = decode_attr("journal", f.attrs.get("journal", ""))
    if not expected:
        return None
    j = read_journal(journal_path(path))
    if j is None or j.token != expected or (
            j.config_key is not None and j.config_key != decode_attr("config_key", f.attrs.get("config_key", ""))):
        return None   # (the token is random: it alone names the session when the open record was damaged)
    return j.after(applied(f))


def overlay(journal: Journal | None, runs: dict, refs: dict, attrs: dict | None = None) -> int:
    """Apply a journal's records to {run_id: (source, attrs)} / {key: (source, attrs)} maps (source is
    a JournalRecord) and, given the root `attrs`, its history; returns how many runs the journal adds."""
    if journal is None:
        return 0
    added = 0
    try:
        fh = open(journal.path, "rb") if any(r.kind == "batch" for r in journal.records) else None
    except OSError:   # removed since it was read (its session just folded it into the file)
        return 0
    try:
        for r in journal.records:
            if r.kind == "batch":
                target = runs if r.key == "run" else refs
                for i, (key, a) in enumerate(zip(r.header.get("keys") or [], r.item_attrs(fh))):
                    target[str(key)] = ((r, i), decode_attrs(a))
                    added += r.key == "run"
                continue
            added += _overlay_one(r, runs, refs, attrs)
    finally:
        if fh is not None:
            fh.close()
    return added


def _overlay_one(r, runs: dict, refs: dict, attrs) -> int:
    """overlay() of a record that is not a batch; returns the runs it adds."""
    if r.kind in ("run", "reference"):
        (runs if r.kind == "run" else refs)[r.key] = ((r, 0), decode_attrs(r.attrs()))
        return int(r.kind == "run")
    if r.kind == "delete":
        # every copy of an item; a batch path or one batch's copy names what the file's checks
        # already set aside (damaged or incomplete), which no reader trusts
        s = split_item_path(r.key)
        if s is not None and s[2] is None:
            (runs if s[0] == "run" else refs).pop(s[1], None)
    elif r.kind == "session" and attrs is not None:
        attrs["history"] = r.header.get("history") or attrs.get("history")
        attrs["updated"] = r.header.get("updated", attrs.get("updated"))
    return 0


def apply_journal(f, j: Journal, path: Path) -> None:
    """Write a journal's run and reference groups into the open HDF5 file `f` (of the results file
    `path`) and delete the groups its delete records name."""
    try:
        fh = open(j.path, "rb")
    except OSError as e:
        raise write_error(path, e, f"read the journal {j.path.name}") from None
    with fh:
        deletions = []   # consecutive delete records: one pass over the batches
        for r in j.records:
            if r.kind == "delete":
                deletions.append(r.key)
                continue
            if deletions:
                delete_items(f, deletions)
                deletions = []
            if r.kind in ("batch", "run", "reference"):
                write_batch(f, r.item_kind, r.batch(fh))
        if deletions:
            delete_items(f, deletions)


class MemGroup:
    """An item's attributes and arrays seen like an h5py group (what trajectory_from_group and the
    checks read)."""

    def __init__(self, enc_attrs: dict, arrays: list):
        self.attrs = enc_attrs
        self._d = dict(arrays)

    def __contains__(self, name):
        return name in self._d

    def __getitem__(self, name):
        return self._d[name]

    def get(self, name, default=None):
        return self._d.get(name, default)

    def __iter__(self):
        return iter(self._d)
