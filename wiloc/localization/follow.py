"""Following a folder that a camera is still filling: each new frame decided as it arrives.

``FolderWatch`` polls a folder and hands out its image files: a JPEG or PNG at first sight (the
reader refuses one cut short, and ``follow`` retries it at the next poll), one of another format
(BMP, TIFF, ...: one cut short may decode) once seen twice with the same size and modification
time. ``follow`` feeds them, in natural order of arrival, through a ``Localizer`` and yields each
decision (or a frame left out, with why), ending after ``idle`` seconds without a new frame.
Nothing here prints or writes; the caller records.
"""
from __future__ import annotations

import os
import stat
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from wiloc.decisions import Decision
from wiloc.errors import FrameError, WilocError
from wiloc.localization.localizer import Localizer
from wiloc.sources.frames import (FORMAT_HEAD_BYTES, IMAGE_SUFFIXES, end_checked, shown_name, subfolders_hint,
                                  type_test, unusable_reason)
from wiloc.sources.natural_order import decimal_form, natural_key

#: Seconds a stable (unchanging) file may stay undecodable before it is left out as bad: a writer
#: that is slow to finish a file gets this long.
SETTLE_SECONDS = 2.0

#: Files already handed out whose size and modification time one poll checks (in turn): a large
#: folder costs no more per poll; a file overwritten in place is noticed within
#: ``files / CHECKS_PER_POLL`` polls (one renamed onto a decided name at the next poll).
CHECKS_PER_POLL = 64

#: A folder listed less than this long after its last change is listed again at the next poll: a
#: file added in the same tick of the file system's clock (2 s on FAT) leaves the folder's time as
#: it was.
RACY_SECONDS = 2.0

#: The longest time between two listings of the folder, for file systems whose folder times lag
#: behind their entries (network file systems' attribute caches).
LISTING_SECONDS = 5.0

#: Why a file already decided and then written again (overwritten, or another file renamed onto
#: its name) is not decided again.
REWRITTEN = ("written again after it was decided; --follow decides each file name once (write each frame "
             "under a new name, or use the Python API's Localizer.observe)")

#: Why a file skipped (a JPEG cut short, say) and then written again (its writer finished it late)
#: is not decided now: each file name is handed out once; a resumed run hands it out again.
COMPLETED = ("completed after it was skipped; not decided now (--follow takes each file name once): a run "
             "resuming this one (the same command again) tries it again")


@dataclass(frozen=True)
class Skipped:
    """A frame left out: its file and why; ``kind`` is ``warning`` for a file already decided
    that was written again (:data:`REWRITTEN`), said once, and for the first frame of a shape
    other than the map's (``Localizer.frame_doubts``: decided, then said); ``note`` for a file
    skipped, then written again (:data:`COMPLETED`)."""

    path: Path
    reason: str
    kind: str = "skipped"

    def __str__(self) -> str:
        """``PATH: REASON``, the path printable whatever bytes its name holds."""
        return f"{shown_name(str(self.path))}: {self.reason}"


def followed_folder(folder: Path) -> Path:
    """``folder`` as a Path; a WilocError naming it when it is no folder that can be followed."""
    folder = Path(folder)
    if not folder.is_dir():
        raise WilocError(folder, "folder does not exist" if not folder.exists() else "not a folder")
    return folder


class FolderWatch:
    """The image files of a folder not handed out yet, each handed out once it may be read (a JPEG
    or PNG at first sight, another format once stable: :meth:`poll`), polled on demand.

    A poll lists the folder only when it may have changed: when its modification time moved since
    the last listing, when that time lies within :data:`RACY_SECONDS` of the listing (a file
    added in the same tick of the file system's clock leaves it unchanged), or
    :data:`LISTING_SECONDS` after the last listing (a file system whose folder times lag). An idle
    poll of a folder of 35,000 decided frames then costs a few calls, not a pass over every name.
    """

    def __init__(self, folder: Path, done: Iterable[str] = (), *,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.folder = followed_folder(folder)
        self._done = set(done)
        self._seen: dict[str, tuple[int, int]] = {}  # name -> (size, mtime_ns) at the last poll
        # handed-out name -> (inode, size, mtime_ns) when handed out (None: not seen yet, a resumed run's)
        self._decided: dict[str, tuple[int, int, int] | None] = dict.fromkeys(self._done)
        self._order = list(self._decided)  # handed-out names in turn for the checks (a name gone from _decided is passed over)
        self._turn = 0  # where the next poll's checks of handed-out files begin
        self._clock = clock
        self._listed: tuple[int, int, float] | None = None  # folder's mtime_ns, wall ns and clock of the last listing
        self._pending: list[str] = []  # image files not handed out at the last listing
        self.rewritten: list[Path] = []  # decided files found written again, each once (the caller empties it)
        self.arriving = False  # whether the last poll saw a file the one before did not
        self._unsure: set[str] = set()  # names the last poll handed out at first sight or changed (not known stable)
        self._forms: dict[str, str] | None = {}  # decimal_form -> name of every name seen; None once numbered
        self._known(self._done)

    def _images(self) -> list[Path]:
        """The image files not handed out, in natural order. A handed-out one found written again
        since (another inode under its name, or another size or modification time) goes to
        :attr:`rewritten`: the inode comes with a listing, a stat costs a call, so each poll stats
        at most :data:`CHECKS_PER_POLL` handed-out files, in turn."""
        if self._changed():
            self._pending = self._listing()
        self._check_decided()
        return [self.folder / name for name in self._pending if name not in self._done]

    def _changed(self) -> bool:
        """Whether the folder may hold entries the last listing did not (see the class)."""
        wall, now = time.time_ns(), self._clock()
        try:
            mtime = os.stat(self.folder).st_mtime_ns
        except OSError:
            mtime = -1
        last, self._listed = self._listed, (mtime, wall, now)
        if last is None or mtime != last[0] or last[1] - mtime < RACY_SECONDS * 1e9 \
                or now - last[2] >= LISTING_SECONDS:
            return True
        self._listed = last
        return False

    def _listing(self) -> list[str]:
        """The folder's image files not handed out, in natural order; handed-out names now on
        another inode (a file renamed onto them) go to :attr:`rewritten`."""
        names = []
        with os.scandir(self.folder) as entries:
            for entry in entries:
                name = entry.name
                if name in self._done:
                    mark = self._decided.get(name)
                    if mark is not None and mark[0] != entry.inode() and not entry.is_symlink():
                        self._rewritten(name)
                    continue
                if name.startswith(".") or os.path.splitext(name)[1].lower() not in IMAGE_SUFFIXES:
                    continue
                if not type_test(entry.is_dir):  # a link that loops: handed out, and left out with its reason
                    names.append(name)
        decimals = self._known(names)
        return sorted(names, key=lambda name: natural_key(name, decimals))

    def subfolders(self) -> str | None:
        """What to say when nothing was handed out and the folder holds sub-folders but no image
        file (a camera's parent folder given by mistake, which would be followed in vain), or None."""
        if self._decided or self._pending:
            return None
        with os.scandir(self.folder) as entries:
            inside = [(entry.name, type_test(entry.is_dir)) for entry in entries if not entry.name.startswith(".")]
        if any(os.path.splitext(name)[1].lower() in IMAGE_SUFFIXES for name, _ in inside):
            return None
        folders = [shown_name(name) for name, is_dir in inside if is_dir]
        return f"no image files yet; {subfolders_hint(folders)}" if folders else None

    def _known(self, names: Iterable[str]) -> bool:
        """Whether dotted numbers still read as decimals once ``names`` are seen, as a batch run of
        the folder decides it over every name (:func:`~wiloc.sources.natural_order.natural_sorted`):
        not once two names seen so far differ only by a fraction's trailing zeros (numbering)."""
        if self._forms is not None:
            for name in names:
                if self._forms.setdefault(decimal_form(name), name) != name:
                    self._forms = None
                    break
        return self._forms is not None

    def _rewritten(self, name: str) -> None:
        del self._decided[name]  # said once
        self.rewritten.append(self.folder / name)

    def _check_decided(self) -> None:
        """Stat the next :data:`CHECKS_PER_POLL` handed-out files: one whose inode, size or
        modification time changed since it was handed out was written again."""
        if len(self._order) > 2 * len(self._decided) + CHECKS_PER_POLL:  # drop the names said rewritten
            self._order = [name for name in self._order if name in self._decided]
        if not self._order:
            return
        start = self._turn % len(self._order)
        for name in (self._order[start:] + self._order[:start])[:CHECKS_PER_POLL]:
            if name not in self._decided:
                continue
            try:
                stat = os.stat(self.folder / name)
            except OSError:  # removed meanwhile, or a dangling link
                continue
            now = (stat.st_ino, stat.st_size, stat.st_mtime_ns)
            before = self._decided[name]
            if before is None:
                self._decided[name] = now
            elif before != now:
                self._rewritten(name)
        self._turn = start + CHECKS_PER_POLL

    def poll(self) -> list[Path]:
        """The files ready to be read, in natural order: those whose size and modification time
        are unchanged since the previous poll, and at first sight (or still changing) those whose
        end the reader checks (:func:`~wiloc.sources.frames.end_checked`: read cut short, they
        fail, and are retried). A file of another format seen for the first time holds back those
        after it in natural order, so that files found together are handed out in that order.
        They count as handed out (call :meth:`retry` for one to come again; :meth:`stable` tells
        which were known stable)."""
        ready, seen, marks, unsure = [], {}, {}, set()
        held = False  # a file of another format first seen by this poll comes before the rest
        for path in self._images():
            try:
                found = path.stat() if not path.is_symlink() or path.exists() else path.lstat()
            except FileNotFoundError:  # renamed or removed meanwhile
                continue
            name = path.name
            seen[name] = (found.st_size, found.st_mtime_ns)
            if self._seen.get(name) != seen[name]:
                if held or not _end_checked(path, found):
                    held = held or name not in self._seen
                    continue
                unsure.add(name)
            ready.append(path)
            marks[name] = (found.st_ino, found.st_size, found.st_mtime_ns)
        self.arriving = any(name not in self._seen for name in seen)
        self._seen = seen
        self._unsure = unsure
        self._done.update(marks)
        self._decided.update(marks)
        self._order.extend(marks)
        return ready

    def stable(self, path: Path) -> bool:
        """Whether ``path``, handed out by the last poll, was unchanged since the poll before (a
        file handed out at first sight, or changed since, may still be being written)."""
        return path.name not in self._unsure

    def taken(self, path: Path) -> None:
        """Note that ``path``, handed out by the last poll, was read whole: one handed out before it
        was known stable is told written again from its size and time now, not from those it
        was handed out with (its writer may have finished it since)."""
        if path.name in self._unsure and path.name in self._decided:
            try:
                found = os.stat(path)
            except OSError:  # removed meanwhile: the mark handed out stays
                return
            self._decided[path.name] = (found.st_ino, found.st_size, found.st_mtime_ns)

    def unsettled(self) -> list[Path]:
        """The image files not handed out (still changing, or just arrived), in natural order."""
        return self._images()

    def retry(self, path: Path) -> None:
        """Hand ``path`` out again (it could not be read yet): at the next poll when it is unchanged
        by then or its end is checked (as :meth:`poll` hands files out)."""
        self._done.discard(path.name)
        self._decided.pop(path.name, None)
        self._listed = None  # list again: a listing since it was handed out left it out


def _end_checked(path: Path, found: os.stat_result) -> bool:
    """Whether ``path`` (``found`` its stat) is a regular file whose first bytes show a format whose
    end the reader checks (:func:`~wiloc.sources.frames.end_checked`); False when it cannot be
    read, or is too short to tell (an empty file is handed out once stable, as other formats)."""
    if not stat.S_ISREG(found.st_mode) or found.st_size < FORMAT_HEAD_BYTES:
        return False
    try:
        handle = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # a FIFO put in its place meanwhile never blocks
    except OSError:
        return False
    try:
        return end_checked(os.read(handle, FORMAT_HEAD_BYTES))
    except OSError:
        return False
    finally:
        os.close(handle)


def follow(localizer: Localizer, watch: FolderWatch, *, idle: float | None, poll: float = 0.2,
           clock: Callable[[], float] = time.monotonic,
           sleep: Callable[[float], None] = time.sleep) -> Iterator[Decision | Skipped]:
    """Decide every frame the watch hands out, as it arrives, until ``idle`` seconds pass without
    one (None: until interrupted), and never before a poll that finds no new file (with ``idle``
    0, a folder's frames are decided, then the run ends). A file handed out before it was known
    stable that cannot be decoded (a JPEG or PNG cut short: its writer may not be done) is
    retried at the next poll; a stable one (an empty one too) is retried for
    :data:`SETTLE_SECONDS` from its first failure (the run does not end meanwhile, nor for
    ``idle`` seconds after), then left out; one that cannot be a frame at all
    (:func:`~wiloc.sources.frames.unusable_reason`) is left out at once. A file still changing when the run ends on ``idle`` (one that failed to
    decode too, then kept changing) is left out with a line, so that every file is named. A file
    left out and then written again gets a note (:data:`COMPLETED`), not decided now."""
    last = clock()
    failing: dict[str, float] = {}  # name -> when it first failed to decode once stable
    left_out: set[str] = set()  # names skipped: one written again was never decided
    first = True
    while True:
        arrived, retried = watch.poll(), False
        if first and not arrived and (hint := watch.subfolders()) is not None:
            yield Skipped(watch.folder, hint, kind="note")
        first = False
        for path in watch.rewritten:
            yield Skipped(path, COMPLETED, kind="note") if path.name in left_out else \
                Skipped(path, REWRITTEN, kind="warning")
        watch.rewritten.clear()
        for path in arrived:
            if (reason := unusable_reason(path)) is not None:
                last = clock()
                left_out.add(path.name)
                yield Skipped(path, reason)
                continue
            said = len(localizer.frame_doubts)
            try:
                decision = localizer.observe(path)
            except FrameError as exc:
                if not watch.stable(path):  # its writer may not be done: retried, the settling time not started
                    watch.retry(path)
                    retried = True
                    continue
                first = failing.setdefault(path.name, clock())
                if clock() - first < SETTLE_SECONDS:
                    watch.retry(path)
                    continue
                del failing[path.name]
                last = clock()
                left_out.add(path.name)
                yield Skipped(path, exc.problem)
                continue
            failing.pop(path.name, None)
            watch.taken(path)
            last = clock()
            for line in localizer.frame_doubts[said:]:  # a camera of another shape than the map's
                yield Skipped(path, line, kind="warning")
            yield decision
        if idle is not None and clock() - last >= idle and not watch.arriving \
                and all(clock() - first >= SETTLE_SECONDS + idle + 2 * poll for first in failing.values()):
            for path in watch.unsettled():
                yield Skipped(path, "still being written when the run ended (not decided; a run resuming "
                                    "this one decides it)")
            return
        if not arrived or failing or retried:
            sleep(poll)
