"""Following a folder that a camera is still filling: each new frame decided as it arrives.

``FolderWatch`` polls a folder and hands out image files once they are complete: seen twice with
the same size and modification time, and decodable. ``follow`` feeds them, in natural order of
arrival, through a ``Localizer`` and yields each decision (or a frame left out, with why), ending
after ``idle`` seconds without a new frame. Nothing here prints or writes; the caller records.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from wiloc.decisions import Decision
from wiloc.errors import FrameError, WilocError
from wiloc.localization.localizer import Localizer
from wiloc.sources.frames import IMAGE_SUFFIXES, natural_key, shown_name, unusable_reason

#: Seconds a stable (unchanging) file may stay undecodable before it is left out as bad: a writer
#: that is slow to finish a file gets this long.
SETTLE_SECONDS = 2.0


@dataclass(frozen=True)
class Skipped:
    """A frame left out: its file and why."""

    path: Path
    reason: str

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
    """The complete image files of a folder not handed out yet, polled on demand."""

    def __init__(self, folder: Path, done: Iterable[str] = ()) -> None:
        self.folder = followed_folder(folder)
        self._done = set(done)
        self._seen: dict[str, tuple[int, int]] = {}  # name -> (size, mtime_ns) at the last poll

    def _images(self) -> list[Path]:
        paths = [p for p in self.folder.iterdir()
                 if not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES and p.name not in self._done
                 and not p.is_dir()]
        return sorted(paths, key=lambda p: natural_key(p.name))

    def poll(self) -> list[Path]:
        """Files whose size and modification time are unchanged since the previous poll, in
        natural order; they count as handed out (call :meth:`retry` for one to come again)."""
        ready, seen = [], {}
        for path in self._images():
            try:
                stat = path.stat() if not path.is_symlink() or path.exists() else path.lstat()
            except FileNotFoundError:  # renamed or removed meanwhile
                continue
            seen[path.name] = (stat.st_size, stat.st_mtime_ns)
            if self._seen.get(path.name) == seen[path.name]:
                ready.append(path)
        self._seen = seen
        self._done.update(p.name for p in ready)
        return ready

    def unsettled(self) -> list[Path]:
        """The image files not handed out (still changing, or just arrived), in natural order."""
        return self._images()

    def retry(self, path: Path) -> None:
        """Hand ``path`` out again once it is stable (it could not be read yet)."""
        self._done.discard(path.name)
        self._seen.pop(path.name, None)


def follow(localizer: Localizer, watch: FolderWatch, *, idle: float | None, poll: float = 0.2,
           clock: Callable[[], float] = time.monotonic,
           sleep: Callable[[float], None] = time.sleep) -> Iterator[Decision | Skipped]:
    """Decide every frame the watch hands out, as it arrives, until ``idle`` seconds pass without
    one (None: until interrupted). A stable file that cannot be decoded (an empty one too) is
    retried for :data:`SETTLE_SECONDS` (the run does not end meanwhile, nor for ``idle`` seconds
    after), then left out; one that cannot be a frame at all (:func:`~wiloc.sources.frames.unusable_reason`)
    is left out at once. A file still changing when the run ends on ``idle`` (one that failed to
    decode too, then kept changing) is left out with a line, so that every file is named."""
    last = clock()
    failing: dict[str, float] = {}  # name -> when it first failed to decode
    while True:
        arrived = watch.poll()
        for path in arrived:
            if (reason := unusable_reason(path)) is not None:
                last = clock()
                yield Skipped(path, reason)
                continue
            try:
                decision = localizer.observe(path)
            except FrameError as exc:
                first = failing.setdefault(path.name, clock())
                if clock() - first < SETTLE_SECONDS:
                    watch.retry(path)
                    continue
                del failing[path.name]
                last = clock()
                yield Skipped(path, exc.problem)
                continue
            failing.pop(path.name, None)
            last = clock()
            yield decision
        if idle is not None and clock() - last >= idle \
                and all(clock() - first >= SETTLE_SECONDS + idle + 2 * poll for first in failing.values()):
            for path in watch.unsettled():
                yield Skipped(path, "still being written when the run ended (not decided; a run resuming "
                                    "this one decides it)")
            return
        if not arrived or failing:
            sleep(poll)
