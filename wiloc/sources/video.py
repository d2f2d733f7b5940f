"""Video files as traversals: recognising them, fingerprinting them cheaply, sampling and decoding
their frames as 8-bit grayscale.

A frame is named by its index in decode order, zero-padded to six digits (``000123``), so names
sort in time order and stay the video's own indices whatever the sampling keeps. Decoding is
OpenCV's bundled FFmpeg; see docs/formats.md for the naming, fingerprint and sampling rules.
"""
from __future__ import annotations

import hashlib
import math
from collections.abc import Container, Iterable, Iterator, Sequence
from dataclasses import dataclass
from numbers import Integral, Real
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from wiloc.errors import ParameterError, WilocError
from wiloc.sources.frames import Fingerprint, text_path

#: File name endings taken for videos (then verified by opening the file): the usual containers
#: of cameras, dashcams and datasets that OpenCV's bundled FFmpeg demuxes.
VIDEO_SUFFIXES: frozenset[str] = frozenset({
    ".avi", ".mkv", ".mov", ".mp4", ".m4v", ".webm", ".mpg", ".mpeg", ".ts", ".mts", ".m2ts",
    ".wmv", ".flv", ".3gp", ".ogv",
})
#: Digits of a frame name: 000000 .. 999999 (9 h 15 min at 30 frames/s); later frames get more
#: digits and still sort after them by natural sort, the order wiloc uses everywhere.
NAME_WIDTH = 6
#: Timestamps are decoder milliseconds in floating point (99.99999 for 100): a frame within this
#: many ms before a start, stop or fps boundary counts as reaching it.
TOLERANCE_MS = 0.5
#: The highest ``fps``: far above any camera's rate (every frame is kept long before it), and low
#: enough that a frame's slot, ms x fps / 1000, stays finite over any video's length.
MAX_FPS = 1e6
#: A video whose decoding stops within this many ms of its container's duration ended whole.
END_MS = 1000.0
#: OpenCV's property of a frame's presentation stamp, which places a stream that starts after 0;
#: None in OpenCV 4.8, which does not give it (such a stream then reads as starting at 0).
_PTS: int | None = getattr(cv2, "CAP_PROP_PTS", None)
#: The fingerprint reads the head and the tail (containers keep their index at either end) and
#: a block at each ninth of the file: 2.5 MiB whatever the file's size.
_END_BYTES = 1 << 20
_MIDDLE_BLOCKS = 8
_BLOCK_BYTES = 1 << 16


def is_video(path: Path) -> bool:
    """Whether `path` names a video by its suffix (and is not a folder); opening it verifies."""
    path = Path(path)
    return path.suffix.lower() in VIDEO_SUFFIXES and not path.is_dir()


def frame_name(index: int) -> str:
    """The name of a video's frame `index`: the index zero-padded to NAME_WIDTH digits."""
    return f"{index:0{NAME_WIDTH}d}"


def video_fingerprint(path: Path) -> Fingerprint:
    """Size, mtime and a blake2b-128 digest of the size, the first and last MiB and 64 KiB at
    each ninth of the file (the whole file when it is smaller than those): cheap on multi-GB
    files, and changed by any re-encoding, cut or append. The mtime is kept but not digested,
    so a touched or restored video keeps its entry."""
    path = Path(path)
    stat = path.stat()
    size = stat.st_size
    digest = hashlib.blake2b(size.to_bytes(8, "little"), digest_size=16)
    with path.open("rb") as handle:
        if size <= 2 * _END_BYTES + _MIDDLE_BLOCKS * _BLOCK_BYTES:
            digest.update(handle.read())
        else:
            parts = [(0, _END_BYTES), (size - _END_BYTES, _END_BYTES)]
            parts += [(size * k // (_MIDDLE_BLOCKS + 1), _BLOCK_BYTES) for k in range(1, _MIDDLE_BLOCKS + 1)]
            for offset, length in parts:
                handle.seek(offset)
                digest.update(handle.read(length))
    return Fingerprint(size=size, mtime_ns=stat.st_mtime_ns, digest=digest.hexdigest())


def _position(value: object, parameter: str) -> int | str:
    """A start/stop value as stored: a frame index (int) or seconds as ``"<number>s"``."""
    if isinstance(value, Integral) and not isinstance(value, bool):
        if value < 0:
            raise ParameterError(parameter, f"must be a frame index >= 0 or seconds such as 12.5s, got {value}")
        return int(value)
    text = value.strip() if isinstance(value, str) else ""
    if text.isdigit():
        return int(text)
    try:
        seconds = float(text[:-1]) if text.endswith("s") else math.nan
    except ValueError:
        seconds = math.nan
    if not math.isfinite(seconds) or seconds < 0:
        raise ParameterError(parameter, f"must be a frame index >= 0 or seconds such as 12.5s, got {value!r}")
    return f"{seconds!r}".removesuffix(".0") + "s"


def _value(bound: int | str) -> float:
    """A start/stop position's number: the frame index, or the seconds."""
    return float(bound) if isinstance(bound, int) else float(bound[:-1])


def _reached(bound: int | str, index: int, timestamp_ms: float) -> bool:
    """Whether a frame is at or after a start/stop position."""
    if isinstance(bound, int):
        return index >= bound
    return timestamp_ms + TOLERANCE_MS >= _value(bound) * 1000.0


def _to_index(bound: int | str, rate: float) -> int:
    """A position as a frame index, converting seconds at the container's frame rate."""
    return bound if isinstance(bound, int) else round(_value(bound) * rate)


@dataclass(frozen=True)
class Sampling:
    """Which frames of a video to describe: a cut, then every K-th frame or about F per second.

    ``start``/``stop`` cut the video to [start, stop): a frame index (``120`` or ``"120"``) or
    seconds of decoder time (``"12.5s"``); ``stop=None`` runs to the end. Of the frames in the
    cut, ``every=K`` keeps the first and every K-th after it; ``fps=F`` instead keeps the first
    frame whose timestamp reaches each multiple of 1/F s after the cut's first frame (every
    frame when F is at least the video's rate). An invalid value raises ParameterError naming it
    (the command line's --every, --fps, --start, --stop).
    """

    every: int = 1
    fps: float | None = None
    start: int | str = 0
    stop: int | str | None = None

    def __post_init__(self) -> None:
        every = self.every
        if not isinstance(every, Integral) or isinstance(every, bool) or every < 1:
            raise ParameterError("every", f"must be a whole number >= 1, got {every!r}")
        object.__setattr__(self, "every", int(every))
        if self.fps is not None:
            fps = self.fps
            if not isinstance(fps, Real) or isinstance(fps, bool) or not 0 < fps <= MAX_FPS:
                raise ParameterError("fps", f"must be a number of frames per second > 0 and at most {MAX_FPS:g}, "
                                            f"got {fps!r}")
            if self.every != 1:
                raise ParameterError("fps", f"cannot be combined with every (got every={self.every})")
            object.__setattr__(self, "fps", float(fps))
        object.__setattr__(self, "start", _position(self.start, "start"))
        if self.stop is not None:
            stop = _position(self.stop, "stop")
            object.__setattr__(self, "stop", stop)
            if type(stop) is type(self.start) and _value(stop) <= _value(self.start):
                raise ParameterError("stop", f"must come after start ({self.start}), got {stop}")

    def pick(self, stream: Iterable[tuple[int, float]]) -> Iterator[tuple[int, float]]:
        """The (index, timestamp ms) pairs of `stream` this sampling keeps, in order. Stops
        drawing from `stream` at the end of the cut, so a lazy decoder reads no further."""
        first: tuple[int, float] | None = None
        next_slot = 0
        for index, timestamp in stream:
            if not _reached(self.start, index, timestamp):
                continue
            if self.stop is not None and _reached(self.stop, index, timestamp):
                return
            if first is None:
                first = (index, timestamp)
            if self.fps is None:
                keep = (index - first[0]) % self.every == 0
            else:
                slot = math.floor((timestamp - first[1] + TOLERANCE_MS) * self.fps / 1000.0)
                keep = slot >= next_slot
                next_slot = max(next_slot, slot + 1)
            if keep:
                yield index, timestamp

    def before_stop(self, index: int, timestamp_ms: float) -> bool:
        """Whether a frame lies before the end of the cut (so that it would be picked or passed)."""
        return self.stop is None or not _reached(self.stop, index, timestamp_ms)

    @property
    def cut(self) -> str:
        """The cut in words, for messages: ``start 120, stop 12.5s``."""
        return f"start {self.start}" + ("" if self.stop is None else f", stop {self.stop}")

    def estimate(self, frame_count: int | None, rate: float) -> int | None:
        """About how many frames `pick` keeps of a video with `frame_count` frames at `rate`
        frames per second (for progress); None when the container does not say."""
        if frame_count is None or rate <= 0:
            return None
        first = min(_to_index(self.start, rate), frame_count)
        last = frame_count if self.stop is None else min(_to_index(self.stop, rate), frame_count)
        span = max(0, last - first)
        return math.ceil(span / self.every if self.fps is None else span * min(1.0, self.fps / rate))


def lost_frames(names: Sequence[str], timestamps_ms: NDArray[np.float64], rate: float) -> str:
    """A note when the timestamps of a video of constant frame rate skip frames between two
    decoded ones (FFmpeg passes over frames it cannot decode in some damaged files, without an
    error), else "". Frames are named in decode order, so from such a gap on a frame's name is
    not its place in time. A video of variable rate (most steps off its nominal interval by
    more than a tenth) is not judged: its steps vary anyway."""
    if rate <= 0 or len(names) < 3:
        return ""
    interval = 1000.0 / rate
    indices = np.array([int(name) for name in names], np.float64)
    expected = np.diff(indices) * interval
    steps = np.diff(np.asarray(timestamps_ms, np.float64))
    if np.mean(np.abs(steps - expected) <= 0.1 * expected) < 0.9:
        return ""
    missing = np.rint((steps - expected) / interval).clip(0)
    if not missing.any():
        return ""
    first = int(np.flatnonzero(missing)[0])
    return (f"its timestamps say {int(missing.sum())} frame(s) are missing, the first after frame {names[first]} "
            f"({steps[first]:.0f} ms to the next at {rate:g} frames/s): frames lost in a damaged file, which the "
            "decoder passed over; from there on a frame's name (its place in decode order) is not its place in time")


@dataclass(frozen=True)
class VideoFrame:
    """One picked frame: its index, decoder timestamp (ms) and grayscale pixels (BGR ones when
    the frames were asked for in colour), or, for the frame where decoding stopped early, no
    pixels and the `problem`."""

    index: int
    timestamp_ms: float | None
    gray: NDArray[np.uint8] | None
    problem: str = ""

    @property
    def name(self) -> str:
        """The frame's name (its zero-padded index)."""
        return frame_name(self.index)


class Video:
    """A video file opened for decoding, positioned on its first frame (which decoded).

    Use as a context manager; `frames` reads the video once, from its first frame.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise WilocError(self.path, "file does not exist")
        text_path(self.path)  # OpenCV crashes on a path that is not UTF-8
        self._capture = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not self._capture.isOpened():
            raise WilocError(self.path, "not a video wiloc can read (no video stream found; an MP4 or "
                                        "MOV cut before its index cannot be opened either)")
        if not self._capture.grab():
            later = self._capture.grab()  # the first frame damaged, or none decodes
            self._capture.release()
            raise WilocError(self.path, f"cannot decode frame {frame_name(0)} (the file is damaged there), and "
                                        "reading stops at a frame that cannot be decoded: no frame can be read"
                             if later else "no frame of this video can be decoded")
        count = int(self._capture.get(cv2.CAP_PROP_FRAME_COUNT))
        #: Frames the container announces (None when it does not say), frames per second (0 when
        #: unknown).
        self.frame_count: int | None = count if count > 0 else None
        self.rate: float = max(0.0, float(self._capture.get(cv2.CAP_PROP_FPS)))
        self._ended: tuple[int, float] | None = None
        self._start_ms = 0.0  # where the stream starts in the container's time (timestamps count from it)

    def __enter__(self) -> Video:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release the decoder."""
        self._capture.release()

    def frames(self, sampling: Sampling, skip: Container[str] = frozenset(),
               colour: bool = False) -> Iterator[VideoFrame]:
        """The frames `sampling` picks, decoded to grayscale (to BGR with `colour`), in order;
        names in `skip` are passed over undecoded (grabbed only). When decoding stops before the
        container's frame count, the last item is the frame where it stopped, without pixels,
        and says so."""
        picked = False  # a frame of the cut came before the one where decoding stopped
        for index, timestamp in sampling.pick(self._grab_all()):
            if frame_name(index) in skip:
                picked = True
                continue
            ok, image = self._capture.retrieve()
            if not ok or image is None:
                yield self._stopped(index, picked)
                return
            picked = True
            yield VideoFrame(index, timestamp, image if colour else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
        if self._ended is not None and sampling.before_stop(*self._ended):
            yield self._stopped(self._ended[0], picked)

    def _grab_all(self) -> Iterator[tuple[int, float]]:
        """(index, timestamp ms) of each frame as it is grabbed (decoded, not yet converted).
        Grabbing that fails before the container's frame count leaves the index and expected
        timestamp of the frame that failed in `_ended`."""
        index = 0
        first: tuple[float, float] | None = None  # the first frame's timestamp and presentation stamp
        while True:
            timestamp = float(self._capture.get(cv2.CAP_PROP_POS_MSEC))
            if index < 2:
                first = self._start(first, timestamp)
            yield index, timestamp
            index += 1
            if not self._capture.grab():
                if self.frame_count is not None and index < self.frame_count and not self._near_end(timestamp):
                    self._ended = (index, timestamp + (1000.0 / self.rate if self.rate else 0.0))
                return

    def _start(self, first: tuple[float, float] | None, timestamp: float) -> tuple[float, float]:
        """Given the first frame's (timestamp, stamp) once the second frame is grabbed, set where
        the stream starts in the container's time: the first frame's presentation stamp in ms,
        its units read off the two frames. A recording cut from a longer one (or a camera's)
        starts after 0, and the container's duration counts from 0, not from its first frame."""
        stamp = float(self._capture.get(_PTS)) if _PTS is not None else math.nan
        if first is not None and math.isfinite(stamp) and stamp > first[1] > 0 and timestamp > first[0]:
            self._start_ms = first[1] * (timestamp - first[0]) / (stamp - first[1]) - first[0]
        return timestamp, stamp

    def _near_end(self, timestamp: float) -> bool:
        """Whether a last frame at `timestamp` (ms) lies at the end of the container's duration,
        within END_MS or two frame intervals: then the video ended where it should, and a frame
        count above its frames is the duration times the nominal rate of a video with a variable
        frame rate (a phone's), not frames lost to a cut."""
        if not self.rate or self.frame_count is None:
            return False
        interval = 1000.0 / self.rate
        return self._start_ms + timestamp + max(END_MS, 2 * interval) >= self.frame_count * interval

    def _stopped(self, index: int, picked: bool) -> VideoFrame:
        """The item for the frame where decoding stopped early, ``picked`` whether the cut had
        frames before it (they are kept)."""
        of = "" if self.frame_count is None else f" of {self.frame_count}"
        kept = (f"; the last good frame is {frame_name(index - 1)}, and the frames up to it are kept" if picked
                else "; the frames before it are not in the cut: no frame of the cut can be decoded" if index > 0
                else "")
        problem = f"cannot decode frame {frame_name(index)}{of} (the file is cut or damaged there){kept}"
        return VideoFrame(index, None, None, problem)
