"""The HDF5 descriptor cache: entry keys, per-frame fingerprints, a crash-safe journal, atomic
writes, a per-entry cross-process lock, and listing.

One entry per (resolved folder, descriptor name, descriptor params) lives in
``<root>/descriptors/<key>.h5`` (layout in docs/formats.md). HDF5 files are never written in place:
every write goes to a temporary file beside the target and is renamed onto it, so a kill leaves
either the old file or the new one. Frames finished during a run are appended to
``<key>.journal`` (one CRC-checked record each), which the next run folds into the HDF5 file.
Every frame in an entry file carries a CRC-32 of what is stored of it: a frame whose bytes no
longer match is dropped when the file is read, and described again by the next run (see
:attr:`Cache.repairs`). Cache files are never written through a symbolic link, and a lock file
lives only while its lock is held.
"""
from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import math
import os
import secrets
import struct
import threading
import time
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone
from json.encoder import encode_basestring_ascii
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import platformdirs

from wiloc import __version__
from wiloc.atomic import process_alive, write_error
from wiloc.errors import CacheBusyError, WilocError
from wiloc.frames import natural_sorted
from wiloc.reprs import short_repr

FORMAT = "wiloc-descriptors"
#: 2: every frame's CRC-32 in ``frames/crc32`` and ``failed/crc32``. Files of another version are
#: described again.
FORMAT_VERSION = 2
#: Seconds a process waits for another one holding the same entry before CacheBusyError: long
#: enough to ride out a concurrent fold or a small describe, short enough to report a stuck run.
DEFAULT_LOCK_TIMEOUT = 60.0
TEMP_SUFFIX = ".wiloc-tmp"
#: Descriptor name of imported matrices, whose rows keep the order of the file they came from.
EXTERNAL = "external"
#: Descriptor shown by `Cache.list_entries` for an entry whose files cannot be read.
UNREADABLE = "unreadable"
_DESCRIPTORS = "descriptors"
_RECORD = struct.Struct("<4sII")  # magic, payload length, CRC-32 of the payload
_MAGIC = b"WJR1"
_JSON_LENGTH = struct.Struct("<I")
#: How often a process waiting for a lock tries again, in seconds.
_LOCK_POLL = 0.05
_NO_FOLLOW = os.O_NOFOLLOW | os.O_CLOEXEC


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
    derived files are keyed by, and per row the decoder timestamp in ms (NaN for image files)."""

    names: list[str]
    data: np.ndarray
    digest: str
    timestamps_ms: np.ndarray | None = None


@dataclass(frozen=True)
class EntryInfo:
    """One line of `Cache.list_entries`."""

    key: str
    folder: str
    descriptor: str
    params: dict[str, Any]
    frames: int
    complete: bool
    size: int
    updated: str
    problem: str = ""  # "<file>: why it cannot be read" when descriptor is "unreadable"


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
                     timestamps_ms=_timestamps(good))

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


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


class Journal:
    """Append-only record of finished frames; one CRC-checked record per write, torn tails ignored."""

    def __init__(self, path: Path, header: EntryHeader) -> None:
        self.path = path
        self._dtype = np.dtype(header.dtype)
        found, _, valid = scan_journal(path)
        if found != header:
            valid = 0
        fd = _open_no_follow(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
        os.ftruncate(fd, valid)
        self._file = os.fdopen(fd, "ab", buffering=0)
        if valid == 0:
            self._write(json.dumps(asdict(header)).encode(), b"")

    def append(self, record: FrameRecord) -> None:
        """Write one frame record; it reaches the OS before this returns, so SIGKILL keeps it."""
        meta = {
            "name": record.name, "size": record.size, "mtime_ns": record.mtime_ns,
            "digest": record.digest, "reason": record.reason,
            "width": record.width, "height": record.height, "timestamp_ms": record.timestamp_ms,
        }
        row = b"" if record.row is None else np.ascontiguousarray(record.row, self._dtype).tobytes()
        self._write(json.dumps(meta).encode(), row)

    def _write(self, meta: bytes, row: bytes) -> None:
        payload = _JSON_LENGTH.pack(len(meta)) + meta + row
        try:
            self._file.write(_RECORD.pack(_MAGIC, len(payload), zlib.crc32(payload)) + payload)
        except OSError as exc:
            raise write_error(self.path, "the cache", exc) from None

    def close(self) -> None:
        """Close the file (records are already written)."""
        self._file.close()


def scan_journal(path: Path) -> tuple[EntryHeader | None, list[FrameRecord], int]:
    """A journal's header, its valid frame records and the byte length they span; reading stops
    at the first torn or corrupt record (a kill mid-write), which the next writer truncates."""
    if path.is_symlink():  # not written by wiloc: never read through it (and replaced on writing)
        return None, [], 0
    try:
        blob = path.read_bytes()
    except FileNotFoundError:
        return None, [], 0
    header, records, offset = None, [], 0
    while offset + _RECORD.size <= len(blob):
        magic, length, crc = _RECORD.unpack_from(blob, offset)
        payload = blob[offset + _RECORD.size: offset + _RECORD.size + length]
        if magic != _MAGIC or len(payload) != length or zlib.crc32(payload) != crc:
            break
        (meta_len,) = _JSON_LENGTH.unpack_from(payload)
        meta = json.loads(payload[_JSON_LENGTH.size: _JSON_LENGTH.size + meta_len])
        if header is None:
            if "key" not in meta:
                break
            header = EntryHeader(**meta)
        else:
            row = payload[_JSON_LENGTH.size + meta_len:]
            values = np.frombuffer(row, header.dtype) if meta["reason"] == "" else None
            records.append(FrameRecord(row=values, **meta))
        offset += _RECORD.size + length
    return header, records, offset


def _open_no_follow(path: Path, flags: int, mode: int = 0o666) -> int:
    """A descriptor on ``path`` opened without following a symbolic link: a link found there
    (wiloc never makes one) is removed, not written through, and a regular file made instead."""
    try:
        return os.open(path, flags | _NO_FOLLOW, mode)
    except OSError as exc:
        if exc.errno != errno.ELOOP:
            raise
    path.unlink()
    return os.open(path, flags | _NO_FOLLOW | os.O_EXCL | os.O_CREAT, mode)


def _same_file(fd: int, path: Path) -> bool:
    """Whether ``path`` still names the file open on ``fd``."""
    try:
        there = os.stat(path, follow_symlinks=False)
    except FileNotFoundError:
        return False
    here = os.fstat(fd)
    return (here.st_dev, here.st_ino) == (there.st_dev, there.st_ino)


def _lock_file(path: Path, deadline: float, busy: Callable[[str], Exception]) -> int:
    """An exclusive ``flock`` on the lock file ``path``, created as needed; the holder's pid is
    written into it. Waits until the monotonic ``deadline``, then raises ``busy(holder pid)``.
    A holder removes the file as it lets go, so a waiter that locked a removed file tries again."""
    while True:
        fd = _open_no_follow(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() >= deadline:
                        raise busy(os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown") from None
                    time.sleep(_LOCK_POLL)
            if _same_file(fd, path):
                os.ftruncate(fd, 0)
                try:
                    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
                except OSError as exc:  # a full disk: the lock is given up as if it was let go
                    path.unlink(missing_ok=True)
                    raise write_error(path, "the cache", exc) from None
                return fd
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)


class Cache:
    """The descriptor cache under one root folder (default: $WILOC_CACHE, else the user cache dir).

    ``repairs`` lists, as ``<file>: what`` lines, the entries this object found damaged and had
    described again (frames failing their checksum, unreadable files), for a front end to report.
    """

    #: Locks this process holds, per thread: lock file -> [descriptor, depth].
    _held = threading.local()

    def __init__(self, root: Path | None = None, lock_timeout: float = DEFAULT_LOCK_TIMEOUT) -> None:
        if root is None:
            env = os.environ.get("WILOC_CACHE")
            root = Path(env) if env else Path(platformdirs.user_cache_dir("wiloc"))
        self.root = Path(root).expanduser().resolve()
        self.lock_timeout = lock_timeout
        self.repairs: list[str] = []
        self._swept = False  # temporary files of dead writers are removed before the first write

    def _make_folder(self, folder: Path) -> None:
        """Create a folder inside the cache (and the cache itself) on first use."""
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise WilocError(self.root, f"cannot create the cache folder ({exc.strerror})") from exc

    # -- primitives shared with other modules -------------------------------------------------

    @contextmanager
    def lock(self, name: str, timeout: float | None = None) -> Iterator[None]:
        """Hold the cross-process lock on `name`, a path relative to the root naming what it guards
        (e.g. ``descriptors/<key>.h5``; the lock file is ``<name>.lock``, holding the holder's
        pid, removed on release). Waits up to `timeout` seconds (default: the cache's
        `lock_timeout`), then raises CacheBusyError naming the holder's pid. Re-entrant within a
        thread."""
        target = self._inside(name)
        path = target.with_name(target.name + ".lock")
        held = self._held.__dict__.setdefault("locks", {})
        if path in held:
            held[path][1] += 1
            try:
                yield
            finally:
                held[path][1] -= 1
            return
        self._make_folder(path.parent)
        deadline = time.monotonic() + (self.lock_timeout if timeout is None else timeout)
        fd = _lock_file(path, deadline, lambda pid: CacheBusyError(target, f"in use by another wiloc process (pid {pid})"))
        held[path] = [fd, 1]
        try:
            yield
        finally:
            del held[path]
            try:
                path.unlink(missing_ok=True)  # while still holding it: a waiter sees it gone and retries
            finally:
                os.close(fd)

    @contextmanager
    def atomic_h5(self, path: Path) -> Iterator[h5py.File]:
        """Yield an HDF5 file open for writing, built in memory; when the block succeeds it is
        written to a temporary file beside `path` and renamed onto it, so readers never see a
        half-written file. HDF5 writing to disk itself fails badly on a full disk (errors while
        freeing its objects, then a crash); Python's writes fail as a WilocError naming `path`."""
        path = Path(path)
        self._make_folder(path.parent)
        if not self._swept:
            self.clean_temp_files()
            self._swept = True
        temp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{TEMP_SUFFIX}")
        with h5py.File(temp, "w", driver="core", backing_store=False) as f:
            yield f
            f.flush()
            image = f.id.get_file_image()
        try:
            with open(temp, "xb") as out:
                out.write(image)
                out.flush()
                os.fsync(out.fileno())
            os.replace(temp, path)
        except OSError as exc:
            raise write_error(path, "the cache", exc) from None
        finally:
            temp.unlink(missing_ok=True)
        directory = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(directory)
        finally:
            os.close(directory)

    def clean_temp_files(self) -> list[Path]:
        """Delete temporary files whose writing process is gone; return what was deleted."""
        removed = []
        for temp in self.root.rglob(f"*{TEMP_SUFFIX}"):
            pid_text = temp.name[: -len(TEMP_SUFFIX)].rsplit(".", 2)[-2]
            if pid_text.isdigit() and not process_alive(int(pid_text)):
                temp.unlink(missing_ok=True)
                removed.append(temp)
        return removed

    def _inside(self, name: str) -> Path:
        relative = Path(name)
        if relative.is_absolute() or ".." in relative.parts or not relative.parts:
            raise ValueError(f"cache name must be a relative path inside the cache: {name!r}")
        return self.root / relative

    # -- descriptor entries -------------------------------------------------------------------

    def entry_name(self, key: str) -> str:
        """The name (relative path) of an entry's HDF5 file, as passed to `lock`."""
        return f"{_DESCRIPTORS}/{key}.h5"

    def entry_path(self, key: str) -> Path:
        """Where an entry's HDF5 file lives."""
        return self.root / self.entry_name(key)

    def journal_path(self, key: str) -> Path:
        """Where an entry's journal lives."""
        return self.root / _DESCRIPTORS / f"{key}.journal"

    def open_journal(self, header: EntryHeader) -> Journal:
        """Open the entry's journal for appending (call with the entry lock held)."""
        self._make_folder(self.root / _DESCRIPTORS)
        return Journal(self.journal_path(header.key), header)

    def read_stored(self, key: str) -> StoredEntry | None:
        """The entry's HDF5 contents with its journal folded in (in memory), or None if absent.
        Frames whose stored bytes fail their checksum are left out (``dropped``; the entry is then
        incomplete); a file that cannot be read, or was written without checksums, counts as
        absent. Either is noted in ``repairs``: the next describe run fills the entry again."""
        path = self.entry_path(key)
        stored = None
        if path.exists():
            try:
                stored = _read_h5(path)
            except (OSError, KeyError, ValueError, TypeError) as exc:
                self.repairs.append(f"{path}: unreadable cache entry ({exc}); described again")
            else:
                if stored is None:
                    self.repairs.append(f"{path}: cache entry written without checksums; described again")
                elif stored.dropped:
                    self.repairs.append(f"{path}: {stored.dropped} frame(s) failed their checksum (the file is "
                                        "damaged); described again")
        header, records, _ = scan_journal(self.journal_path(key))
        if header is None:
            return stored
        if stored is None or stored.header != header:
            stored = StoredEntry(header, created=_now())
        stored.records.update((r.name, r) for r in records)
        stored.journaled = bool(records)
        stored.complete = stored.complete and not records and not stored.dropped
        return stored

    def write_entry(self, stored: StoredEntry, complete: bool) -> Entry:
        """Write the entry atomically, then drop its journal, whose records are now in the file.
        Call with the entry lock held. Returns the entry as written."""
        header = stored.header
        entry = stored.entry()
        records = stored.ordered()
        good = [r for r in records if r.row is not None]
        bad = [r for r in records if r.row is None]
        text = h5py.string_dtype()
        with self.atomic_h5(self.entry_path(header.key)) as f:
            attrs = asdict(header)
            attrs.update(
                format=FORMAT, format_version=FORMAT_VERSION, params=json.dumps(header.params, sort_keys=True),
                natural_max=np.nan if header.natural_max is None else header.natural_max,
                wiloc_version=__version__, created=stored.created or _now(), updated=_now(),
                complete=complete, digest=entry.digest,
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
        self.journal_path(header.key).unlink(missing_ok=True)
        stored.complete = complete
        stored.journaled = False
        return entry

    def read_entry(self, key: str) -> Entry:
        """The entry stored under `key` (journaled frames included), as listed by `list_entries`;
        WilocError when absent or damaged (describe its folder again to repair it)."""
        stored = self.read_stored(key)
        if stored is None or stored.dropped:
            raise WilocError(self.entry_path(key), self.repairs[-1] if stored is not None or self.repairs
                             else "no such cache entry")
        return stored.entry()

    def list_entries(self) -> list[EntryInfo]:
        """Every descriptor entry in the cache, including ones only a killed run's journal holds.
        An entry whose files cannot be read is listed as descriptor "unreadable", incomplete,
        with the reason in `problem`."""
        keys = sorted({p.stem for p in (self.root / _DESCRIPTORS).glob("*.h5")}
                      | {p.stem for p in (self.root / _DESCRIPTORS).glob("*.journal")})
        infos = []
        for key in keys:
            stats = {}
            for p in (self.entry_path(key), self.journal_path(key)):
                with suppress(FileNotFoundError):  # a run may fold its journal meanwhile
                    stats[p] = p.stat()
            if not stats:  # deleted since the listing
                continue
            updated = datetime.fromtimestamp(max(st.st_mtime for st in stats.values()), timezone.utc)
            info = EntryInfo(
                key=key, folder="", descriptor=UNREADABLE, params={}, frames=0, complete=False,
                size=sum(st.st_size for st in stats.values()),
                updated=updated.isoformat(timespec="seconds"),
            )
            try:
                filled = self._entry_info(info, with_journal=self.journal_path(key) in stats)
            except WilocError as exc:
                filled = replace(info, problem=str(exc))
            if filled is not None:
                infos.append(filled)
        return infos

    def _entry_info(self, info: EntryInfo, with_journal: bool) -> EntryInfo | None:
        """`info` filled in from the entry's files; None while a run has only opened its journal
        (no header written yet: nothing to list); WilocError naming the file if unreadable."""
        path = self.entry_path(info.key)
        header = None
        if path.exists():
            try:
                with h5py.File(path, "r") as f:
                    header, complete = _header_from_attrs(f.attrs), bool(f.attrs["complete"])
                    frames = len(f["frames/name"])
            except (OSError, KeyError, ValueError, TypeError) as exc:
                raise WilocError(path, f"unreadable cache entry ({exc}); describing its folder again "
                                       "rebuilds it") from exc
        stored = self.read_stored(info.key) if with_journal else None
        if stored is not None:  # a killed run's journal adds frames
            header, complete = stored.header, stored.complete
            frames = sum(r.row is not None for r in stored.records.values())
        if header is None:
            return None
        return replace(info, folder=header.folder, descriptor=header.descriptor,
                       params=header.params, frames=frames, complete=complete)


def _header_from_attrs(attrs: h5py.AttributeManager) -> EntryHeader:
    natural_max = float(attrs["natural_max"])
    return EntryHeader(
        key=str(attrs["key"]), folder=str(attrs["folder"]), descriptor=str(attrs["descriptor"]),
        params=json.loads(attrs["params"]), metric=str(attrs["metric"]), scale=float(attrs["scale"]),
        natural_max=None if np.isnan(natural_max) else natural_max,
        dtype=str(attrs["dtype"]), length=int(attrs["length"]),
    )


def _read_h5(path: Path) -> StoredEntry | None:
    """The entry file's contents, frames failing their checksum left out; None for a file of
    another format version (written without checksums)."""
    with h5py.File(path, "r") as f:
        if int(f.attrs.get("format_version", 0)) != FORMAT_VERSION:
            return None
        header = _header_from_attrs(f.attrs)
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
            if group == "frames":
                widths, heights = g["width"][()].tolist(), g["height"][()].tolist()
                stamps = [None if math.isnan(stamp) else stamp for stamp in g["timestamp_ms"][()].tolist()]
                records = [FrameRecord(name, sizes[i], mtimes[i], digests[i], rows[i], "", widths[i], heights[i],
                                       stamps[i])
                           for i, name in enumerate(names)]
            else:
                reasons = [r.decode(errors="replace") for r in g["reason"][()]]
                records = [FrameRecord(name, sizes[i], mtimes[i], digests[i], None, reasons[i])
                           for i, name in enumerate(names)]
            for record, crc in zip(records, g["crc32"][()]):
                if checksum(record, dtype) == crc:
                    stored.records[record.name] = record
                else:
                    stored.dropped += 1
    return stored
