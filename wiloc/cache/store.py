"""The HDF5 descriptor cache: entry keys, per-frame fingerprints, a crash-safe journal, atomic
writes, a per-entry cross-process lock, and listing.

One entry per (resolved folder, descriptor name, descriptor params) lives in
``<root>/descriptors/<key>.h5`` (layout in docs/formats.md). HDF5 files are never written in place:
every write goes to a temporary file beside the target and is renamed onto it, so a kill leaves
either the old file or the new one. Frames finished during a run are appended to
``<key>.journal`` (one CRC-checked record each), which the next run folds into the HDF5 file.
A frame of an entry file whose bytes no longer match their CRC-32 (``wiloc.cache.entries``, which
holds the entry format) is dropped when the file is read, and described again by the next run
(see :attr:`Cache.repairs`). Cache files are never written through a symbolic link, and a lock file
lives only while its lock is held.
"""
from __future__ import annotations

import errno
import fcntl
import json
import os
import secrets
import struct
import threading
import time
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import asdict, dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import platformdirs

from wiloc.atomic import process_alive, write_error
from wiloc.cache.entries import Entry, EntryHeader, FrameRecord, StoredEntry, header_from_attrs, now, read_h5, write_h5
from wiloc.errors import CacheBusyError, ParameterError, WilocError

#: Seconds a process waits for another one holding the same entry before CacheBusyError: long
#: enough to ride out a concurrent fold or a small describe, short enough to report a stuck run.
DEFAULT_LOCK_TIMEOUT = 60.0
TEMP_SUFFIX = ".wiloc-tmp"
#: Descriptor shown by `Cache.list_entries` for an entry whose files cannot be read.
UNREADABLE = "unreadable"
_DESCRIPTORS = "descriptors"
_RECORD = struct.Struct("<4sII")  # magic, payload length, CRC-32 of the payload
_MAGIC = b"WJR1"
_JSON_LENGTH = struct.Struct("<I")
#: How often a process waiting for a lock tries again, in seconds.
_LOCK_POLL = 0.05
#: How long past its deadline a process refused a lock keeps trying while the holder's pid is not
#: in the file yet: a holder writes it just after it locks, so a busy error can name it.
_PID_GRACE = 1.0
_NO_FOLLOW = os.O_NOFOLLOW | os.O_CLOEXEC


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



class Journal:
    """Append-only record of finished frames; one CRC-checked record per write, torn tails ignored."""

    def __init__(self, path: Path, header: EntryHeader) -> None:
        self.path = path
        self._dtype = np.dtype(header.dtype)
        found, _, valid, _ = scan_journal(path)
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


def _check_own_file(path: Path) -> None:
    """A WilocError naming ``path`` when something other than a regular file is where a cache file
    belongs: a folder (never written over, after a whole run described in vain), or a FIFO or
    device, whose opening would block for ever."""
    if path.is_dir():
        raise WilocError(path, "a folder where a cache file belongs; remove it")
    if path.exists() and not path.is_file():
        raise WilocError(path, "not a regular file (a FIFO or a device) where a cache file belongs; remove it")


def scan_journal(path: Path) -> tuple[EntryHeader | None, list[FrameRecord], int, bool]:
    """A journal's header, its valid frame records, the byte length they span, and whether the
    reading stopped at damage: a whole record that fails its check. A record cut short (a kill
    mid-write) is expected and ends the reading too; the next writer truncates either."""
    if path.is_symlink():  # not written by wiloc: never read through it (and replaced on writing)
        return None, [], 0, False
    try:
        blob = path.read_bytes()
    except FileNotFoundError:
        return None, [], 0, False
    header, records, offset, damaged = None, [], 0, False
    while offset + _RECORD.size <= len(blob):
        magic, length, crc = _RECORD.unpack_from(blob, offset)
        payload = blob[offset + _RECORD.size: offset + _RECORD.size + length]
        if magic != _MAGIC or len(payload) != length or zlib.crc32(payload) != crc:
            damaged = magic != _MAGIC or len(payload) == length
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
    return header, records, offset, damaged


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


def lock_file(path: Path, deadline: float, busy: Callable[[str], Exception]) -> int:
    """An exclusive ``flock`` on the lock file ``path``, created as needed; the holder's pid is
    written into it. Waits until the monotonic ``deadline``, then raises ``busy(holder pid)`` (while
    the holder has locked but not yet written its pid, for up to :data:`_PID_GRACE` more).
    A holder removes the file as it lets go, so a waiter that locked a removed file tries again."""
    while True:
        fd = _open_no_follow(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if (now := time.monotonic()) >= deadline:
                        holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
                        if holder or now >= deadline + _PID_GRACE:
                            raise busy(holder or "unknown") from None
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

    @classmethod
    def given(cls, cache: Cache | str | os.PathLike | None) -> Cache:
        """The cache a caller of the library gave: a ``Cache``, a folder's path (as ``--cache DIR``
        names one) or None for the default folder; anything else a ParameterError naming ``cache``."""
        if isinstance(cache, Cache):
            return cache
        if cache is None or isinstance(cache, (str, os.PathLike)):
            return cls(None if cache is None else Path(cache))
        raise ParameterError("cache", f"a Cache or a cache folder's path, got {type(cache).__name__}")

    def _make_folder(self, folder: Path) -> None:
        """Create a folder inside the cache (and the cache itself) on first use."""
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            if exc.errno == errno.EEXIST and folder != self.root:  # a file where the cache keeps its folder
                raise WilocError(folder, "a file where a cache folder belongs; remove it") from None
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
        try:
            fd = lock_file(path, deadline, lambda pid: CacheBusyError(target, f"in use by another wiloc process (pid {pid})"))
        except OSError as exc:
            if exc.errno not in (errno.EACCES, errno.EPERM, errno.EROFS):
                raise
            raise WilocError(self.root, f"cannot lock {name} ({exc.strerror}): the cache folder must be writable, "
                                        "entries are locked while read; give one that is") from None
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
        for own in (path, self.journal_path(key)):
            _check_own_file(own)
        stored = None
        if path.exists():
            try:
                stored = read_h5(path)
            except (OSError, KeyError, ValueError, TypeError) as exc:
                self.repairs.append(f"{path}: unreadable cache entry ({exc}); described again")
            else:
                if stored is None:
                    self.repairs.append(f"{path}: cache entry written without checksums; described again")
                elif stored.dropped:
                    self.repairs.append(f"{path}: {stored.dropped} frame(s) failed their checksum (the file is "
                                        "damaged); described again")
        header, records, _, damaged = scan_journal(self.journal_path(key))
        if damaged:
            where = f"a record after the first {len(records)} frame(s)" if header else "its first record (the header)"
            self.repairs.append(f"{self.journal_path(key)}: {where} failed its checksum (the file is damaged); the "
                                "frames after it described again")
        if header is None:
            return stored
        if stored is None or stored.header != header:
            stored = StoredEntry(header, created=now())
        stored.records.update((r.name, r) for r in records)
        stored.journaled = bool(records)
        stored.complete = stored.complete and not records and not stored.dropped
        return stored

    def write_entry(self, stored: StoredEntry, complete: bool) -> Entry:
        """Write the entry atomically, then drop its journal, whose records are now in the file.
        Call with the entry lock held. Returns the entry as written."""
        header = stored.header
        entry = stored.entry()
        with self.atomic_h5(self.entry_path(header.key)) as f:
            write_h5(f, stored, entry, complete)
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
        folder = self.root / _DESCRIPTORS
        if folder.exists() and not folder.is_dir():  # an empty list would read as an emptied cache
            raise WilocError(folder, "a file where a cache folder belongs; remove it")
        keys = sorted({p.stem for p in folder.glob("*.h5")} | {p.stem for p in folder.glob("*.journal")})
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
            except OSError as exc:  # its journal unreadable (a folder in its place, no permission)
                filled = replace(info, problem=f"{exc.filename or self.journal_path(key)}: unreadable ({exc.strerror})")
            if filled is not None:
                infos.append(filled)
        return infos

    def _entry_info(self, info: EntryInfo, with_journal: bool) -> EntryInfo | None:
        """`info` filled in from the entry's files; None while a run has only opened its journal
        (no header written yet: nothing to list); WilocError naming the file if unreadable."""
        path = self.entry_path(info.key)
        header = None
        _check_own_file(path)
        if path.exists():
            try:
                with h5py.File(path, "r") as f:
                    header, complete = header_from_attrs(f.attrs), bool(f.attrs["complete"])
                    str(f.attrs["digest"])  # read as describe reads it: an attribute damaged past reading is told
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

