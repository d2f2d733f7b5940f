"""Descriptor cache entries and their on-disk form: headers and entry keys, per-frame records
and their CRC-32, content digests, and the HDF5 layout of an entry file, read and written.

An entry file carries a CRC-32 of what it stores of each frame: a frame whose bytes no longer
match is left out when the file is read (``StoredEntry.dropped``). The cache folder, its locks and
the journal of frames finished during a run are ``wiloc.cache.store``'s.
"""
from __future__ import annotations

import hashlib
import json
import math
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Sequence, Sized
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from json.encoder import encode_basestring_ascii
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from wiloc.reprs import short_repr
from wiloc.sources.natural_order import natural_sorted
from wiloc.version import __version__

FORMAT = "wiloc-descriptors"
#: 2: every frame's CRC-32 in ``frames/crc32`` and ``failed/crc32``. Files of another version are
#: described again.
FORMAT_VERSION = 2
#: Descriptor name of imported matrices, whose rows keep the order of the file they came from.
EXTERNAL = "external"


@dataclass(frozen=True)
class EntryHeader:
    """What identifies an entry and how to read its rows."""

    key: str
    folder: str
    descriptor: str
    params: dict[str, Any]
    metric: str
    scale: float
    natural_max: float | None
    dtype: str
    length: int

    @classmethod
    def create(cls, folder: str, descriptor: str, params: dict[str, Any], metric: str, scale: float,
               natural_max: float | None, dtype: np.dtype | str, length: int) -> EntryHeader:
        """The header of the entry for `folder` described by `descriptor` with `params`, its key
        derived from those three; params are normalised through JSON so they compare equal to
        what the file holds."""
        params = json.loads(json.dumps(params, sort_keys=True))
        return cls(
            key=entry_key(folder, descriptor, params), folder=folder, descriptor=descriptor,
            params=params, metric=metric, scale=float(scale),
            natural_max=None if natural_max is None else float(natural_max),
            dtype=np.dtype(dtype).str, length=int(length),
        )


@dataclass(frozen=True)
class FrameRecord:
    """One frame of an entry: its fingerprint and either its descriptor row or why it failed.
    A video's frames carry the video's fingerprint and their decoder timestamp."""

    name: str
    size: int
    mtime_ns: int
    digest: str
    row: np.ndarray | None
    reason: str = ""
    width: int = 0
    height: int = 0
    timestamp_ms: float | None = None


@short_repr
@dataclass(frozen=True)
class Entry(EntryHeader):
    """A cached descriptor matrix: the header's fields, rows in frame order named by file name
    (a video's frames by index), a digest of the content (names, fingerprints, params) that
    derived files are keyed by, per row the decoder timestamp in ms (NaN for image files), the
    frames' most common size in pixels, (width, height) (None where no size is recorded: rows
    imported from a matrix), and each size with its count of frames, the most common first."""

    names: list[str]
    data: np.ndarray
    digest: str
    timestamps_ms: np.ndarray | None = None
    frame_size: tuple[int, int] | None = None
    frame_sizes: tuple[tuple[tuple[int, int], int], ...] = ()

@dataclass
class StoredEntry:
    """An entry as found on disk: its header, frame records by name, and bookkeeping."""

    header: EntryHeader
    records: dict[str, FrameRecord] = field(default_factory=dict)
    complete: bool = False
    created: str = ""
    journaled: bool = False
    dropped: int = 0  # frames whose stored bytes failed their checksum: not in ``records``
    # the entry file's descriptor matrix as read, and the view of each of its rows that a record holds
    read_matrix: tuple[np.ndarray, list[np.ndarray]] | None = field(default=None, repr=False, compare=False)

    def ordered(self, names: Sequence[str] | None = None) -> list[FrameRecord]:
        """The records in frame order: a folder's by natural sort of names (as traversals list
        them); an imported matrix's in its file's row order, which is its time order. A caller
        that holds exactly the records' names in that order (a traversal's listing) passes them as
        `names`, sparing a second natural sort of the same names."""
        if self.header.descriptor == EXTERNAL:
            return list(self.records.values())
        if names is None:
            names = natural_sorted(self.records)
        return [self.records[name] for name in names]

    def entry(self, names: Sequence[str] | None = None) -> Entry:
        """The descriptor matrix of the frames that have a row, in frame order (`names`: as for
        `ordered`)."""
        h = self.header
        good = [r for r in self.ordered(names) if r.row is not None]
        if self._read_in_order(good):
            data = self.read_matrix[0]  # type: ignore[index]
        else:
            data = np.empty((len(good), h.length), np.dtype(h.dtype))
            for i, record in enumerate(good):
                data[i] = record.row
        return Entry(**asdict(h), names=[r.name for r in good], data=data, digest=entry_digest(h, good),
                     timestamps_ms=_timestamps(good), **_frame_sizes(good))

    def _read_in_order(self, good: list[FrameRecord]) -> bool:
        """Whether ``good`` are the rows of :attr:`read_matrix`, row after row: the matrix is then
        the entry's, with no copy (the common case: a folder checked against its entry file, whose
        frames are stored in frame order; copying 35,000 rows into fresh memory cost 0.2 s)."""
        if self.read_matrix is None:
            return False
        matrix, rows = self.read_matrix
        return (matrix.dtype == np.dtype(self.header.dtype) and matrix.shape == (len(good), self.header.length)
                and all(record.row is row for record, row in zip(good, rows)))


def _timestamps(records: list[FrameRecord]) -> np.ndarray:
    """Each record's timestamp in ms, NaN where it has none (image files)."""
    return np.array([np.nan if r.timestamp_ms is None else r.timestamp_ms for r in records], np.float64)


def _frame_sizes(records: list[FrameRecord]) -> dict[str, Any]:
    """``frame_size``, the most common (width, height) among ``records`` that record one, and
    ``frame_sizes``, each with its count, the most common first."""
    sizes = Counter((r.width, r.height) for r in records if r.width > 0 and r.height > 0).most_common()
    return {"frame_size": sizes[0][0] if sizes else None, "frame_sizes": tuple(sizes)}


def checksum(record: FrameRecord, dtype: np.dtype | str) -> int:
    """CRC-32 of what an entry file stores of a frame: its name, fingerprint and either its size,
    timestamp and row bytes, or why it failed."""
    if record.row is None:
        fields: list[Any] = [record.name, record.size, record.mtime_ns, record.digest, record.reason]
        row = b""
    else:
        fields = [record.name, record.size, record.mtime_ns, record.digest, record.width, record.height,
                  record.timestamp_ms]
        row = np.ascontiguousarray(record.row, np.dtype(dtype)).tobytes()
    return zlib.crc32(_json_list(fields).encode() + row)


def _json_float(value: float) -> str:
    """A float as json.dumps writes it: its repr, or NaN, Infinity, -Infinity."""
    return float.__repr__(value) if math.isfinite(value) else json.dumps(value)


#: How json.dumps writes a value of each of these exact types (bool, subclasses and others: absent).
_JSON_WRITERS: dict[type, Callable[[Any], str]] = {
    str: encode_basestring_ascii, int: int.__repr__, float: _json_float, type(None): lambda _: "null",
}


def _json_list(values: list[Any]) -> str:
    """``json.dumps(values)`` character for character, written here when every value is a str,
    int, float or None (in a quarter of the time: json.dumps' set-up per call dominated checking
    an entry's frames); anything else goes to json.dumps itself."""
    try:
        return "[" + ", ".join([_JSON_WRITERS[type(value)](value) for value in values]) + "]"
    except KeyError:
        return json.dumps(values)


def entry_key(folder: str, descriptor: str, params: dict[str, Any]) -> str:
    """The key of an entry: a hash of the resolved folder, descriptor name and params."""
    text = json.dumps([folder, descriptor, params], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def entry_digest(header: EntryHeader, records: Iterable[FrameRecord]) -> str:
    """A hash over the entry key, descriptor params, names and row content digests: it changes
    whenever the rows do, so results derived from an entry can tell they are stale."""
    h = hashlib.sha256(json.dumps([header.key, header.descriptor, header.params], sort_keys=True).encode())
    for record in records:
        h.update(f"{record.name}\0{record.digest}\n".encode())
    return h.hexdigest()


def now() -> str:
    """The present UTC time as an entry file records it."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def write_h5(f: h5py.File, stored: StoredEntry, entry: Entry, complete: bool) -> None:
    """The entry file's layout written into ``f`` (open for writing): header attributes, the
    descriptor matrix of ``entry`` and, per frame with a row and per failed frame, what it
    stores with its CRC-32 (docs/formats.md)."""
    header = stored.header
    records = stored.ordered()
    good = [r for r in records if r.row is not None]
    bad = [r for r in records if r.row is None]
    text = h5py.string_dtype()
    attrs = asdict(header)
    attrs.update(
        format=FORMAT, format_version=FORMAT_VERSION, params=json.dumps(header.params, sort_keys=True),
        natural_max=np.nan if header.natural_max is None else header.natural_max,
        wiloc_version=__version__, created=stored.created or now(), updated=now(),
        complete=complete, complete_crc=_complete_crc(header.key, complete, len(good), len(bad)), digest=entry.digest,
    )
    f.attrs.update(attrs)
    f.create_dataset("descriptors", data=entry.data)
    for group, rows in (("frames", good), ("failed", bad)):
        g = f.create_group(group)
        g.create_dataset("crc32", data=np.array([checksum(r, header.dtype) for r in rows], np.uint32))
        g.create_dataset("name", data=[r.name for r in rows], dtype=text)
        g.create_dataset("size", data=np.array([r.size for r in rows], np.int64))
        g.create_dataset("mtime_ns", data=np.array([r.mtime_ns for r in rows], np.int64))
        g.create_dataset("digest", data=[r.digest for r in rows], dtype=text)
        if group == "frames":
            g.create_dataset("width", data=np.array([r.width for r in rows], np.int32))
            g.create_dataset("height", data=np.array([r.height for r in rows], np.int32))
            g.create_dataset("timestamp_ms", data=_timestamps(rows))
        else:
            g.create_dataset("reason", data=[r.reason for r in rows], dtype=text)


def _complete_crc(key: str, complete: bool, frames: int, failed: int) -> int:
    """CRC-32 of an entry's ``complete`` flag with its key and frame counts: a flag flipped on disk
    would take a video's or bag's partial entry for whole, its other frames never described."""
    return zlib.crc32(f"{key}\0{bool(complete)}\0{frames}\0{failed}".encode())


def header_from_attrs(attrs: h5py.AttributeManager) -> EntryHeader:
    """The header an entry file's attributes record."""
    natural_max = float(attrs["natural_max"])
    return EntryHeader(
        key=str(attrs["key"]), folder=str(attrs["folder"]), descriptor=str(attrs["descriptor"]),
        params=json.loads(attrs["params"]), metric=str(attrs["metric"]), scale=float(attrs["scale"]),
        natural_max=None if np.isnan(natural_max) else natural_max,
        dtype=str(attrs["dtype"]), length=int(attrs["length"]),
    )


def _same_lengths(group: str, names: list[str], **columns: Sized) -> None:
    """A ValueError (an unreadable entry, described again) naming the first of a group's per-frame
    datasets that does not hold one value per frame name: a file damaged that way read other
    frames' values, or ran past the end."""
    for column, values in columns.items():
        if len(values) != len(names):
            where = "descriptors" if column == "descriptors" else f"{group}/{column}"
            raise ValueError(f"{where} holds {len(values)} values for {len(names)} frames")


def read_h5(path: Path) -> StoredEntry | None:
    """The entry file's contents, frames failing their checksum left out; None for a file of
    another format version (written without checksums)."""
    with h5py.File(path, "r") as f:
        if int(f.attrs.get("format_version", 0)) != FORMAT_VERSION:
            return None
        header = header_from_attrs(f.attrs)
        stored = StoredEntry(header, complete=bool(f.attrs["complete"]), created=str(f.attrs["created"]))
        data = f["descriptors"][()]
        rows = list(data)  # each row's view, made in one go
        stored.read_matrix = (data, rows)
        dtype = np.dtype(header.dtype)  # made once, not per frame by checksum
        for group in ("frames", "failed"):
            g = f[group]
            # damaged bytes may be no UTF-8: decoded anyway, they fail the frame's checksum
            names = [n.decode(errors="replace") for n in g["name"][()]]
            digests = [d.decode(errors="replace") for d in g["digest"][()]]
            sizes, mtimes = g["size"][()].tolist(), g["mtime_ns"][()].tolist()  # Python ints, in one go
            crcs = g["crc32"][()]
            if group == "frames":
                widths, heights = g["width"][()].tolist(), g["height"][()].tolist()
                stamps = [None if math.isnan(stamp) else stamp for stamp in g["timestamp_ms"][()].tolist()]
                _same_lengths(group, names, digest=digests, size=sizes, mtime_ns=mtimes, crc32=crcs, width=widths,
                              height=heights, timestamp_ms=stamps, descriptors=rows)
                records = [FrameRecord(name, sizes[i], mtimes[i], digests[i], rows[i], "", widths[i], heights[i],
                                       stamps[i])
                           for i, name in enumerate(names)]
            else:
                reasons = [r.decode(errors="replace") for r in g["reason"][()]]
                _same_lengths(group, names, digest=digests, size=sizes, mtime_ns=mtimes, crc32=crcs, reason=reasons)
                records = [FrameRecord(name, sizes[i], mtimes[i], digests[i], None, reasons[i])
                           for i, name in enumerate(names)]
            for record, crc in zip(records, crcs):
                if checksum(record, dtype) == crc:
                    stored.records[record.name] = record
                else:
                    stored.dropped += 1
            if group == "frames" and not stored.dropped and str(f.attrs["digest"]) != entry_digest(header, records):
                raise ValueError("its digest attribute does not match its frames")  # the attribute damaged
        counts = len(f["frames/name"]), len(f["failed/name"])
        if "complete_crc" in f.attrs and int(f.attrs["complete_crc"]) != _complete_crc(header.key, stored.complete,
                                                                                        *counts):
            raise ValueError("its complete attribute does not match its check")  # (a file written before has none)
    stored.complete = stored.complete and not stored.dropped  # a video's or bag's missing frames described again
    return stored
