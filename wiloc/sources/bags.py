"""ROS bags as traversals: recognising them, fingerprinting them, and reading the images of one
topic (and the travelled distance of an odometry topic) with the ``rosbags`` library, which
needs no ROS installation (the optional extra ``wiloc[rosbags]``).

A ROS 1 bag is a ``.bag`` file; a ROS 2 bag is a folder holding ``metadata.yaml`` and its sqlite3
(``.db3``) or MCAP storage, or one such storage file on its own. A frame is named by its message's header stamp, ``t<seconds>.<nine
digits of nanoseconds>`` (``t1700000000.123456789``), so names sort in time order; see
docs/formats.md for the naming and sampling rules.
"""
from __future__ import annotations

import hashlib
from collections.abc import Container, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from wiloc.errors import FrameError, UsageError, WilocError
from wiloc.sources.frames import Fingerprint, decode_colour, decode_gray, to_uint8
from wiloc.sources.video import Sampling, video_fingerprint

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
ODOMETRY = "nav_msgs/msg/Odometry"
#: Raw image conversions by the colour part of an encoding's name: channels, and OpenCV's codes
#: to grayscale and to BGR (None: none needed). A Bayer mosaic is demosaiced as cv_bridge does
#: (ROS's ``bayer_rggb`` is OpenCV's ``BayerBG``: OpenCV names the pattern by the second row's
#: second and third pixels).
_COLOURS: dict[str, tuple[int, int | None, int | None]] = {
    "mono": (1, None, cv2.COLOR_GRAY2BGR), "rgb": (3, cv2.COLOR_RGB2GRAY, cv2.COLOR_RGB2BGR),
    "bgr": (3, cv2.COLOR_BGR2GRAY, None), "rgba": (4, cv2.COLOR_RGBA2GRAY, cv2.COLOR_RGBA2BGR),
    "bgra": (4, cv2.COLOR_BGRA2GRAY, cv2.COLOR_BGRA2BGR),
    "bayer_rggb": (1, cv2.COLOR_BayerBG2GRAY, cv2.COLOR_BayerBG2BGR),
    "bayer_bggr": (1, cv2.COLOR_BayerRG2GRAY, cv2.COLOR_BayerRG2BGR),
    "bayer_gbrg": (1, cv2.COLOR_BayerGR2GRAY, cv2.COLOR_BayerGR2BGR),
    "bayer_grbg": (1, cv2.COLOR_BayerGB2GRAY, cv2.COLOR_BayerGB2BGR),
}
#: Raw image encodings read (sensor_msgs' names, 8 and 16 bits of each): channels, sample type
#: and the conversions to grayscale and to BGR; 16-bit samples are converted, then scaled by
#: 255/65535.
ENCODINGS: dict[str, tuple[int, np.dtype, int | None, int | None]] = {
    f"{colour}{bits}": (channels, np.dtype(np.uint8 if bits == 8 else np.uint16), gray, bgr)
    for colour, (channels, gray, bgr) in _COLOURS.items() for bits in (8, 16)
}
INSTALL = 'reading ROS bags needs the rosbags package: pip install "wiloc[rosbags]"'
#: File name endings of bags: ROS 1, and the ROS 2 storage files rosbags reads on their own.
BAG_SUFFIXES = frozenset({".bag", ".mcap", ".db3"})


def is_bag(path: Path) -> bool:
    """Whether `path` names a ROS bag: a ``.bag``, ``.mcap`` or ``.db3`` file, or a folder holding
    ``metadata.yaml``."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.suffix.lower() in BAG_SUFFIXES


def frame_name(stamp_ns: int, repeat: int = 0) -> str:
    """The name of a frame stamped `stamp_ns` (``t1700000000.123456789``); the `repeat`-th later
    frame of the same stamp gets ``_2``, ``_3``, ... after it."""
    seconds, nanoseconds = divmod(int(stamp_ns), 1_000_000_000)
    return f"t{seconds}.{nanoseconds:09d}" + (f"_{repeat + 1}" if repeat else "")


def stamp_of(name: str) -> int:
    """The stamp in nanoseconds a frame name holds (:func:`frame_name` read back)."""
    seconds, _, rest = name.removeprefix("t").partition(".")
    return int(seconds) * 1_000_000_000 + int(rest[:9])


def bag_fingerprint(path: Path) -> Fingerprint:
    """A ROS 1 bag's fingerprint as a video's (size, mtime and a digest of sampled blocks); a
    ROS 2 bag folder's combines those of its files (metadata and storage), so a file added,
    cut or rewritten changes it."""
    path = Path(path)
    if not path.is_dir():
        return video_fingerprint(path)
    files = sorted(p for p in path.iterdir() if p.is_file() and not p.name.startswith("."))
    prints = [video_fingerprint(p) for p in files]
    digest = hashlib.blake2b(digest_size=16)
    for file, fp in zip(files, prints):
        digest.update(f"{file.name}\0{fp.digest}\n".encode())
    return Fingerprint(size=sum(fp.size for fp in prints), mtime_ns=max((fp.mtime_ns for fp in prints), default=0),
                       digest=digest.hexdigest())


@dataclass(frozen=True)
class BagFrame:
    """One picked frame: its name, stamp (ms since the epoch) and grayscale pixels (BGR ones when
    the frames were asked for in colour), or, when its image cannot be decoded, no pixels and
    the `problem`."""

    name: str
    timestamp_ms: float
    gray: NDArray[np.uint8] | None
    problem: str = ""


def _rosbags(path: Path) -> Any:
    """The rosbags reader and a type store for bags that carry no message definitions; without
    rosbags installed, a UsageError naming the bag and the extra to install."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise UsageError(path, INSTALL) from None
    return AnyReader, get_typestore(Stores.LATEST)


class Bag:
    """A ROS bag opened for reading; :meth:`choose` picks the image topic that :meth:`frames`
    reads. Use as a context manager."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise WilocError(self.path, "file does not exist")
        reader, typestore = _rosbags(self.path)
        with _damaged(self.path):
            self._reader = reader([self.path], default_typestore=typestore)
            self._reader.open()
            self.topics: dict[str, str | None] = {name: info.msgtype for name, info in self._reader.topics.items()}
            self._counts = {name: info.msgcount for name, info in self._reader.topics.items()}
        self.note = ""
        self.topic = ""

    def choose(self, topic: str | None) -> None:
        """Read the image topic `topic` (checked), or with None the bag's only image topic,
        which ``note`` then names."""
        self.topic = self._image_topic(topic)

    @property
    def count(self) -> int:
        """Messages on the chosen topic."""
        return self._counts[self.topic]

    @property
    def rate(self) -> float:
        """The chosen topic's messages per second of the bag's log time (0 when unknown)."""
        duration = self._reader.duration / 1e9
        return (self.count - 1) / duration if self.count > 1 and duration > 0 else 0.0

    def __enter__(self) -> Bag:
        return self

    def __exit__(self, *exc: object) -> None:
        self._reader.close()

    def of_type(self, *msgtypes: str) -> list[str]:
        """The bag's topics of these message types."""
        return sorted(name for name, msgtype in self.topics.items() if msgtype in msgtypes)

    def _listed(self, msgtypes: tuple[str, ...], what: str) -> str:
        """The bag's topics of `msgtypes` as an error message lists them."""
        have = self.of_type(*msgtypes)
        return f"its {what} topics: {', '.join(have)}" if have else f"it has no {what} topic"

    def _checked(self, topic: str, msgtypes: tuple[str, ...], what: str) -> None:
        """WilocError unless the bag has `topic` with messages of one of `msgtypes`."""
        if topic not in self.topics:
            raise WilocError(self.path, f"no topic {topic}; {self._listed(msgtypes, what)}")
        if self.topics[topic] not in msgtypes:
            raise WilocError(self.path, f"topic {topic} holds {self.topics[topic]} messages, not "
                                        f"{' or '.join(msgtypes)}; {self._listed(msgtypes, what)}")

    def _image_topic(self, topic: str | None) -> str:
        """The image topic to read: `topic` checked, else the bag's only one."""
        kinds = (IMAGE, COMPRESSED)
        if topic is not None:
            self._checked(topic, kinds, "image")
            return topic
        images = self.of_type(*kinds)
        if len(images) == 1:
            self.note = f"{self.path}: reading its only image topic {images[0]}"
            return images[0]
        if not images:
            raise WilocError(self.path, f"no image topic ({IMAGE} or {COMPRESSED}); its topics: "
                                        f"{', '.join(sorted(self.topics)) or 'none'}")
        raise UsageError(None, f"{self.path} has {len(images)} image topics, give one: {', '.join(images)}",
                         parameter="topic")

    def _messages(self, topic: str) -> Iterator[tuple[int, Any]]:
        """(stamp ns, message) of each message on `topic` in log order: the header stamp, or the
        log time where the header's stamp is zero (a driver that does not set it)."""
        connections = [c for c in self._reader.connections if c.topic == topic]
        with _damaged(self.path):
            for connection, logged, raw in self._reader.messages(connections=connections):
                message = self._reader.deserialize(raw, connection.msgtype)
                stamp = message.header.stamp
                stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
                yield (stamp_ns if stamp_ns > 0 else logged), message

    def frames(self, sampling: Sampling, min_size: tuple[int, int] | None = None,
               skip: Container[str] = frozenset(), colour: bool = False) -> Iterator[BagFrame]:
        """The frames `sampling` picks (start and stop by message index on the topic, or by
        seconds after the first message's stamp), decoded to grayscale (to 8-bit BGR with
        `colour`, for a network), in order; names in `skip` are passed over undecoded. A
        compressed JPEG is decoded as a folder's would be (``min_size``: the reduced decode the
        descriptor allows)."""
        current: list[tuple[str, int, Any]] = []

        def stream() -> Iterator[tuple[int, float]]:
            first = None
            seen: dict[int, int] = {}
            for index, (stamp_ns, message) in enumerate(self._messages(self.topic)):
                first = stamp_ns if first is None else first
                repeat = seen[stamp_ns] = seen.get(stamp_ns, -1) + 1
                current[:] = [(frame_name(stamp_ns, repeat), stamp_ns, message)]
                yield index, (stamp_ns - first) / 1e6

        for _ in sampling.pick(stream()):
            name, stamp_ns, message = current[0]
            if name in skip:
                continue
            where = f"{self.path}/{name}"
            try:
                gray = self._pixels(message, where, min_size, colour)
            except FrameError as exc:
                yield BagFrame(name, stamp_ns / 1e6, None, exc.problem)
                continue
            yield BagFrame(name, stamp_ns / 1e6, gray)

    def _pixels(self, message: Any, where: str, min_size: tuple[int, int] | None,
                colour: bool) -> NDArray[np.uint8]:
        """A message's image as 8-bit grayscale (BGR with `colour`): a compressed one decoded
        with OpenCV as an image file is, a raw one converted from its encoding (another encoding
        stops the run: every frame would fail)."""
        data = np.asarray(message.data, dtype=np.uint8)
        if self.topics[self.topic] == COMPRESSED:
            return decode_colour(data, where) if colour else decode_gray(data, where, min_size)
        encoding = message.encoding.lower()
        if encoding not in ENCODINGS:
            raise WilocError(self.path, f"topic {self.topic}: image encoding '{message.encoding}' is not "
                                        f"supported (supported: {', '.join(ENCODINGS)})")
        channels, dtype, to_gray, to_bgr = ENCODINGS[encoding]
        conversion = to_bgr if colour else to_gray
        height, width, step = int(message.height), int(message.width), int(message.step)
        row = width * channels * dtype.itemsize
        if height == 0 or width == 0 or step < row or data.size < height * step:
            raise FrameError(where, f"image data of {data.size} bytes does not hold {width} x {height} "
                                    f"{encoding} pixels with rows of {step} bytes")
        rows = data[:height * step].reshape(height, step)[:, :row]
        order = ">" if message.is_bigendian else "<"
        pixels = np.ascontiguousarray(rows).view(dtype.newbyteorder(order)).reshape(height, width, channels)
        pixels = pixels.astype(dtype, copy=False)  # native byte order
        image = (pixels if colour else pixels[:, :, 0]) if conversion is None else cv2.cvtColor(pixels, conversion)
        return to_uint8(image, where)

    def arclength(self, topic: str, names: list[str]) -> NDArray[np.float64]:
        """The distance travelled along `topic`'s ``nav_msgs/msg/Odometry`` positions (x, y, z)
        up to each frame of `names` (by their stamps), from the first of them: the summed steps
        between odometry messages, interpolated linearly at the frames' stamps. A WilocError when
        frames lie outside the messages' time span (:meth:`_covered`)."""
        self._checked(topic, (ODOMETRY,), "odometry")
        stamps, positions = [], []
        for stamp_ns, message in self._messages(topic):
            point = message.pose.pose.position
            stamps.append(stamp_ns)
            positions.append((point.x, point.y, point.z))
        if len(stamps) < 2:
            raise WilocError(self.path, f"topic {topic} holds {len(stamps)} odometry message(s); it needs at least 2")
        order = np.argsort(np.asarray(stamps, np.int64), kind="stable")
        times = np.asarray(stamps, np.int64)[order]
        route = np.asarray(positions, np.float64)[order]
        travelled = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(route, axis=0), axis=1))]
        frames = np.array([stamp_of(n) for n in names], np.int64)
        self._covered(topic, names, frames, times)
        at = np.interp(frames - times[0], times - times[0], travelled)
        return at - at[0] if len(at) else at

    def _covered(self, topic: str, names: list[str], frames: NDArray[np.int64], times: NDArray[np.int64]) -> None:
        """A WilocError, worded as an odometry CSV lacking frames is, when frames' stamps (`frames`,
        of `names`) lie outside the odometry messages' stamps (`times`, sorted) by more than a
        margin: interpolation holds the position at the span's end there, a step of 0 each, and the
        filter takes the robot for standing still."""
        # The margin: one median interval between messages, and at least 0.1 s. A camera and an
        # odometry topic seldom start and stop together (a few ms to one message apart); a frame
        # that close to an end is held at most about one message's step short, an error of the size
        # interpolating across a dropped message makes anyway, and at walking or driving speed
        # within the filter's motion noise. Further out the frames stand still for as long as
        # they lie outside.
        margin = max(float(np.median(np.diff(times))), 1e8)  # at least 2 messages (checked above)
        outside = (frames < times[0] - margin) | (frames > times[-1] + margin)
        if not outside.any():
            return
        span = f"its messages span {frame_name(int(times[0]))} to {frame_name(int(times[-1]))}"
        if outside.all():
            raise WilocError(self.path, f"topic {topic}: no odometry for any of its {len(names)} frame(s) "
                                        f"({names[0]} to {names[-1]}): {span}")
        first = names[int(np.flatnonzero(outside)[0])]
        raise WilocError(self.path, f"topic {topic}: no odometry for {int(outside.sum())} frame(s), first "
                                    f"{first!r}: {span}")


@contextmanager
def _damaged(path: Path) -> Iterator[None]:
    """Whatever rosbags raises on a damaged or cut bag, as one WilocError naming the bag."""
    try:
        yield
    except WilocError:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever rosbags raises
        detail = " ".join(str(arg) for arg in exc.args) or type(exc).__name__
        raise WilocError(path, f"cannot read this ROS bag (damaged or cut short?): {detail}") from None
