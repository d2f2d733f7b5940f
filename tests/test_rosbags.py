"""ROS bags as traversals: bags written here with rosbags' own writers (ROS 1, ROS 2 with sqlite3
and MCAP storage) from small generated images; names, sampling, cache, encodings, odometry,
bad bags; and Gardens Point written into bags localizing as its folder does."""
from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import ends_in_one_error
from typer.testing import CliRunner

from wiloc import Localizer, api
from wiloc.cache.store import Cache
from wiloc.cli import app
from wiloc.description.describing import describe_bag
from wiloc.descriptors.registry import get_descriptor
from wiloc.errors import WilocError
from wiloc.localization.run_files import read_run
from wiloc.sources.bags import Bag, frame_name, is_bag, stamp_of
from wiloc.sources.frames import read_gray

pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
from rosbags.typesys import Stores, get_typestore

runner = CliRunner()
KINDS = ("ros1", "sqlite3", "mcap")
T0 = 1_700_000_000 * 10**9 + 123_456_789  # the first frame's stamp, ns
IMAGE, COMPRESSED, ODOMETRY = "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "nav_msgs/msg/Odometry"


class BagWriter:
    """Messages into a ROS 1 bag or a ROS 2 bag (sqlite3 or MCAP storage), serialized by rosbags."""

    def __init__(self, path: Path, kind: str) -> None:
        self.ros1 = kind == "ros1"
        self.store = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        self.writer = Writer1(path) if self.ros1 else Writer2(
            path, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3)
        self.writer.open()
        self.connections: dict[str, object] = {}

    def header(self, stamp: int) -> object:
        t = self.store.types
        time = t["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
        return t["std_msgs/msg/Header"](**({"seq": 0} if self.ros1 else {}), stamp=time, frame_id="camera")

    def write(self, topic: str, stamp: int, message: object) -> None:
        msgtype = message.__msgtype__
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        data = (self.store.serialize_ros1 if self.ros1 else self.store.serialize_cdr)(message, msgtype)
        self.writer.write(self.connections[topic], stamp, data)

    def image(self, topic: str, stamp: int, pixels: np.ndarray, encoding: str = "mono8") -> None:
        pixels = np.ascontiguousarray(pixels)
        self.write(topic, stamp, self.store.types[IMAGE](
            header=self.header(stamp), height=pixels.shape[0], width=pixels.shape[1], encoding=encoding,
            is_bigendian=0, step=pixels.strides[0], data=pixels.view(np.uint8).ravel()))

    def compressed(self, topic: str, stamp: int, data: bytes, fmt: str) -> None:
        self.write(topic, stamp, self.store.types[COMPRESSED](
            header=self.header(stamp), format=fmt, data=np.frombuffer(data, np.uint8)))

    def odometry(self, topic: str, stamp: int, x: float, y: float) -> None:
        t = self.store.types
        point = t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0)
        pose = t["geometry_msgs/msg/Pose"](position=point, orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
        zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        self.write(topic, stamp, t[ODOMETRY](
            header=self.header(stamp), child_frame_id="base",
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                                                              covariance=np.zeros(36))))

    def close(self) -> None:
        self.writer.close()


def scenes(count: int, seed: int = 0, size: tuple[int, int] = (48, 64)) -> list[np.ndarray]:
    """`count` smooth random grayscale images."""
    rng = np.random.default_rng(seed)
    return [cv2.GaussianBlur(rng.integers(0, 256, size, dtype=np.uint8), (5, 5), 0) for _ in range(count)]


def stamps(count: int, period_ns: int = 100_000_000) -> list[int]:
    return [T0 + i * period_ns for i in range(count)]


def write_bag(path: Path, kind: str, images: list[np.ndarray], *, topic: str = "/camera/image_raw",
              compressed: str | None = None, odometry: str | None = None) -> Path:
    """A bag of `images` on `topic` at 10 Hz from T0: raw mono8, or `compressed` ('.png', '.jpg');
    with `odometry`, that topic holds positions speeding up along x (x = 0.05 i^2 at the i-th
    message), at 20 Hz from T0."""
    path = path.with_suffix(".bag") if kind == "ros1" else path
    writer = BagWriter(path, kind)
    for stamp, pixels in zip(stamps(len(images)), images):
        if compressed is None:
            writer.image(topic, stamp, pixels)
        else:
            writer.compressed(topic, stamp, cv2.imencode(compressed, pixels)[1].tobytes(), compressed[1:])
    if odometry is not None:
        for i, stamp in enumerate(stamps(2 * len(images), 50_000_000)):
            writer.odometry(odometry, stamp, 0.05 * i * i, 0.0)
    writer.close()
    return path


@pytest.mark.parametrize("kind", KINDS)
def test_frames_are_named_by_stamp_and_described_like_the_images(kind: str, tmp_path: Path) -> None:
    images = scenes(12)
    bag = write_bag(tmp_path / "run", kind, images)
    assert is_bag(bag)
    spec = get_descriptor("sad")
    report = describe_bag(bag, spec, Cache(tmp_path / "cache"))
    assert report.entry.names == [frame_name(s) for s in stamps(12)]
    assert report.entry.names[0] == "t1700000000.123456789" and stamp_of(report.entry.names[3]) == stamps(12)[3]
    assert (report.computed, report.reused, report.failed) == (12, 0, [])
    assert report.notes == [f"{bag}: reading its only image topic /camera/image_raw"]
    expected = np.stack([spec.compute(image) for image in images])
    np.testing.assert_array_equal(report.entry.data, expected)
    if kind != "ros1":  # a ROS 2 bag's storage file alone is a bag too
        storage = next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
        alone = describe_bag(storage, spec, Cache(tmp_path / "cache"))
        assert is_bag(storage) and alone.entry.names == report.entry.names
        np.testing.assert_array_equal(alone.entry.data, expected)


def test_sampling_by_index_and_by_stamp(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "run", "mcap", scenes(20))
    cache = Cache(tmp_path / "cache")
    spec = get_descriptor("sad")
    names = [frame_name(s) for s in stamps(20)]
    every = describe_bag(bag, spec, cache, api.Sampling(every=3, start=2, stop=15))
    assert every.entry.names == names[2:15:3]
    fps = describe_bag(bag, spec, cache, api.Sampling(fps=2.5, start="0.5s"))  # 10 Hz: every 4th from 0.5 s
    assert fps.entry.names == names[5::4]
    with pytest.raises(WilocError, match="holds no image of topic /camera/image_raw"):
        describe_bag(bag, spec, cache, api.Sampling(start=25))


def test_the_cache_is_reused_and_a_changed_bag_is_seen(tmp_path: Path, cache_dir: Path) -> None:
    bag = write_bag(tmp_path / "run", "sqlite3", scenes(8))
    first = runner.invoke(app, ["describe", str(bag), "--json"])
    assert first.exit_code == 0, first.output
    assert f"note {bag}: reading its only image topic /camera/image_raw" in first.stderr
    again = api.describe([bag], "sad")[0]
    assert (again.computed, again.reused) == (0, 8)
    other = api.describe([bag], "sad", sampling=api.Sampling(every=2))[0]
    assert (other.computed, other.frames) == (4, 4)
    listed = runner.invoke(app, ["describe", "--list"], env={"COLUMNS": "200"}).stdout
    assert "every=2, topic=/camera/image_raw" in listed and "start=0" not in listed
    for file in bag.iterdir():
        if file.suffix == ".db3":
            file.unlink()
    changed = write_bag(tmp_path / "changed", "sqlite3", scenes(9, seed=1))
    for file in changed.iterdir():
        file.rename(bag / file.name)
    redone = api.describe([bag], "sad")[0]
    assert (redone.computed, redone.frames) == (9, 9)


def test_raw_and_lossless_compressed_images_give_the_same_descriptors(tmp_path: Path) -> None:
    images = scenes(6)
    cache = Cache(tmp_path / "cache")
    spec = get_descriptor("sad")
    raw = describe_bag(write_bag(tmp_path / "raw", "ros1", images), spec, cache)
    png = describe_bag(write_bag(tmp_path / "png", "mcap", images, compressed=".png"), spec, cache)
    assert raw.entry.names == png.entry.names
    np.testing.assert_array_equal(raw.entry.data, png.entry.data)


@pytest.mark.parametrize("encoding", ["mono16", "rgb8", "bgr8", "rgba8", "bgra8", "rgb16", "bgra16"])
def test_raw_encodings_are_read_as_grayscale(encoding: str, tmp_path: Path) -> None:
    gray = scenes(1)[0]
    pixels = {"mono16": gray.astype(np.uint16) * 257,
              "rgb8": cv2.cvtColor(gray, cv2.COLOR_GRAY2RGB), "bgr8": cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR),
              "rgba8": cv2.cvtColor(gray, cv2.COLOR_GRAY2RGBA), "bgra8": cv2.cvtColor(gray, cv2.COLOR_GRAY2BGRA),
              "rgb16": cv2.cvtColor(gray, cv2.COLOR_GRAY2RGB).astype(np.uint16) * 257,
              "bgra16": cv2.cvtColor(gray, cv2.COLOR_GRAY2BGRA).astype(np.uint16) * 257}[encoding]
    writer = BagWriter(tmp_path / "run.bag", "ros1")
    writer.image("/cam", T0, pixels, encoding)
    writer.close()
    with Bag(tmp_path / "run.bag") as bag:
        bag.choose("/cam")
        frames = list(bag.frames(api.Sampling()))
    assert len(frames) == 1 and frames[0].problem == ""
    np.testing.assert_array_equal(frames[0].gray, gray)


@pytest.mark.parametrize("kind", ["bgr8", "rgb8", "bgra16", "mono8", "png", "bayer_rggb8"])
def test_frames_in_colour_are_bgr_as_a_file_decodes(kind: str, tmp_path: Path) -> None:
    """For a network (a colour descriptor): each encoding's pixels as 8-bit BGR, as OpenCV decodes
    an image file of the same picture."""
    rng = np.random.default_rng(3)
    bgr = cv2.GaussianBlur(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), (9, 9), 0)
    writer = BagWriter(tmp_path / "run.bag", "ros1")
    if kind == "png":
        writer.compressed("/cam", T0, cv2.imencode(".png", bgr)[1].tobytes(), "png")
        expected = bgr
    elif kind == "mono8":
        gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        writer.image("/cam", T0, gray, kind)
        expected = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    elif kind == "bayer_rggb8":
        writer.image("/cam", T0, mosaic(bgr, "rggb"), kind)
        expected = cv2.cvtColor(mosaic(bgr, "rggb"), cv2.COLOR_BayerBG2BGR)
    else:
        pixels = {"bgr8": bgr, "rgb8": bgr[:, :, ::-1], "bgra16": cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA).astype(np.uint16) * 257}
        writer.image("/cam", T0, pixels[kind], kind)
        expected = bgr
    writer.close()
    with Bag(tmp_path / "run.bag") as bag:
        bag.choose("/cam")
        [frame] = list(bag.frames(api.Sampling(), colour=True))
    assert frame.gray.dtype == np.uint8 and frame.gray.shape == (48, 64, 3)
    np.testing.assert_array_equal(frame.gray, expected)


def mosaic(bgr: np.ndarray, pattern: str) -> np.ndarray:
    """A colour image as a camera's Bayer sensor sees it: `pattern` names the colours of each 2 x 2
    cell's pixels, row by row ('rggb': red top left, blue bottom right)."""
    out = np.zeros(bgr.shape[:2], bgr.dtype)
    for k, colour in enumerate(pattern):
        out[k // 2::2, k % 2::2] = bgr[k // 2::2, k % 2::2, "bgr".index(colour)]
    return out


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
@pytest.mark.parametrize("bits", [8, 16])
def test_bayer_images_are_demosaiced_by_their_pattern(pattern: str, bits: int, tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    bgr = cv2.GaussianBlur(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), (9, 9), 0)
    raw = mosaic(bgr, pattern)
    writer = BagWriter(tmp_path / "run.bag", "ros1")
    writer.image("/cam", T0, raw if bits == 8 else raw.astype(np.uint16) * 257, f"bayer_{pattern}{bits}")
    writer.close()
    with Bag(tmp_path / "run.bag") as bag:
        bag.choose("/cam")
        [frame] = list(bag.frames(api.Sampling()))
    assert frame.problem == "" and frame.gray.dtype == np.uint8 and frame.gray.shape == raw.shape
    truth = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(int)
    # demosaiced by the right pattern: nearer the scene's gray than half the error of any wrong one (OpenCV's
    # 16-bit demosaicing rounds otherwise than its 8-bit one in some releases, so the errors need not be equal)
    errors = sorted(np.abs(cv2.cvtColor(raw, getattr(cv2, f"COLOR_Bayer{code}2GRAY")).astype(int) - truth).mean()
                    for code in ("BG", "RG", "GR", "GB"))
    assert np.abs(frame.gray.astype(int) - truth).mean() < 0.5 * errors[1] and errors[0] < 0.5 * errors[1]


def test_odometry_topic_gives_the_distance_between_frames(tmp_path: Path, cache_dir: Path) -> None:
    bag = write_bag(tmp_path / "run", "mcap", scenes(10), odometry="/odom")
    names = [frame_name(s) for s in stamps(10)][::3]
    with Bag(bag) as opened:
        arc = opened.arclength("/odom", names)
    np.testing.assert_allclose(arc, [0.0, 1.8, 7.2, 16.2])  # frame k at x = 0.2 k^2
    ref = write_bag(tmp_path / "ref", "ros1", scenes(10), odometry="/odom")
    every = api.Sampling(every=3)
    run = api.localize(bag, reference=ref, method="catgraph", odometry_topic="/odom", sampling=every)
    assert run.results.header.odometry_topic == "/odom" and len(run.decisions) == 4
    csv = tmp_path / "odometry.csv"  # the same positions as an odometry CSV: the same decisions
    csv.write_text("".join(f"{name},{0.2 * (3 * k) ** 2},0\n" for k, name in enumerate(names)))
    given = api.localize(bag, reference=ref, method="catgraph", odometry=csv, map_odometry=csv, sampling=every)
    np.testing.assert_array_equal(run.decisions.confidence, given.decisions.confidence)
    plain = api.localize(bag, reference=ref, method="catgraph", sampling=every)
    assert not np.array_equal(run.decisions.confidence, plain.decisions.confidence)
    loop = {"frontier": 1}  # sequence mode: the bag's own odometry places its frames as the map's nodes
    own = api.localize(bag, method="catgraph", odometry_topic="/odom", exclude_recent=2, method_params=loop)
    csv.write_text("".join(f"{frame_name(s)},{0.2 * k ** 2},0\n" for k, s in enumerate(stamps(10))))
    assert own.results.header.params["odometry"] is True and np.isfinite(own.decisions.confidence[-1])
    np.testing.assert_array_equal(own.decisions.confidence, api.localize(
        bag, method="catgraph", odometry=csv, exclude_recent=2, method_params=loop).decisions.confidence)


def test_a_bag_localizes_against_a_folder_from_the_command_line(tmp_path: Path, cache_dir: Path) -> None:
    images = scenes(10)
    folder = tmp_path / "ref"
    folder.mkdir()
    for i, image in enumerate(images):
        cv2.imwrite(str(folder / f"img{i}.png"), image)
    bag = write_bag(tmp_path / "run", "ros1", images, topic="/cam")
    out = tmp_path / "run.csv"
    result = runner.invoke(app, ["localize", str(bag), "--map", str(folder), "--topic", "/cam",
                                 "--method", "threshold", "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    frames = [line.split(",")[0] for line in out.read_text().splitlines() if line.startswith("t17")]
    assert frames == [frame_name(s) for s in stamps(10)]


def test_a_map_bag_of_another_image_topic_is_read_from_map_topic(tmp_path: Path, cache_dir: Path) -> None:
    """A map recorded by another driver names its images otherwise: --map-topic reads the map
    from its own topic (here besides another camera's, which --topic alone would not choose)."""
    images = scenes(8)
    bag = write_bag(tmp_path / "run", "ros1", images, topic="/camera/image_raw/compressed", compressed=".png")
    writer = BagWriter(tmp_path / "map.bag", "ros1")
    for stamp, same, other in zip(stamps(8), images, scenes(8, seed=5)):
        writer.image("/cam0/image_raw", stamp, same)
        writer.image("/cam1/image_raw", stamp, other)
    writer.close()
    ref, out = tmp_path / "map.bag", tmp_path / "run.csv"
    args = ["localize", str(bag), "--map", str(ref), "--topic", "/camera/image_raw/compressed",
            "--method", "threshold", "--out", str(out), "--json"]
    ends_in_one_error(runner.invoke(app, args), 1, f"{ref}: no topic /camera/image_raw/compressed; its image "
                                                   "topics: /cam0/image_raw, /cam1/image_raw")  # as before
    result = runner.invoke(app, [*args, "--map-topic", "/cam0/image_raw"])
    assert result.exit_code == 0, result.output
    header = out.read_text()
    assert "# topic: /camera/image_raw/compressed\n# map_topic: /cam0/image_raw\n" in header
    drawn = runner.invoke(app, ["evaluate", str(out), "--matrix-plot", str(tmp_path / "matrix.png")])  # map: its topic
    assert drawn.exit_code == 0 and (tmp_path / "matrix.png").is_file(), drawn.output
    run = api.localize(bag, reference=ref, method="threshold", map_topic="/cam0/image_raw")  # the query's only topic
    np.testing.assert_array_equal(run.decisions.match, np.arange(8))  # each frame found where it was
    assert (run.results.header.topic, run.results.header.map_topic) == (None, "/cam0/image_raw")
    assert read_run(out).header.map_topic == "/cam0/image_raw"


def test_map_topic_needs_a_map_bag(tmp_path: Path, cache_dir: Path) -> None:
    bag = write_bag(tmp_path / "run", "ros1", scenes(6))
    folder = tmp_path / "folder"
    folder.mkdir()
    for i, image in enumerate(scenes(6)):
        cv2.imwrite(str(folder / f"img{i}.png"), image)
    ends_in_one_error(runner.invoke(app, ["localize", str(bag), "--map", str(folder), "--map-topic", "/cam0"]), 2,
                      "--map-topic: applies to a ROS bag map only")
    ends_in_one_error(runner.invoke(app, ["localize", str(bag), "--map-topic", "/cam0"]), 2,
                      "--map-topic: applies to map mode (--map) only")
    ends_in_one_error(runner.invoke(app, ["localize", str(folder), "--map", str(bag), "--follow",
                                          "--map-topic", "/camera/image_raw"]), 2, "--follow", "--map-topic")
    assert not list(Path(cache_dir).rglob("*.h5"))
    with pytest.raises(WilocError) as refused:
        api.localize(bag, method="threshold", map_topic="/camera/image_raw")
    assert refused.value.parameter == "map_topic"


# ------------------------------------------------------------------------------------ bad bags

def two_topics(tmp_path: Path) -> Path:
    writer = BagWriter(tmp_path / "two.bag", "ros1")
    writer.image("/left", T0, scenes(1)[0])
    writer.image("/right", T0, scenes(1)[0])
    writer.odometry("/odom", T0, 0.0, 0.0)
    writer.close()
    return tmp_path / "two.bag"


def test_the_localizer_takes_a_map_bag_of_several_image_topics(tmp_path: Path, cache_dir: Path) -> None:
    writer = BagWriter(tmp_path / "two.bag", "ros1")
    left, right = scenes(6, seed=1), scenes(6, seed=2)
    for stamp, a, b in zip(stamps(6), left, right):
        writer.image("/left", stamp, a)
        writer.image("/right", stamp, b)
    writer.close()
    with pytest.raises(WilocError, match="has 2 image topics, give one"):
        Localizer(tmp_path / "two.bag", method="threshold")
    loc = Localizer(tmp_path / "two.bag", topic="/right", method="threshold")
    assert loc.observe(right[3]).match_name == frame_name(stamps(6)[3])
    loc.save(tmp_path / "run.npz")
    assert Localizer.load(tmp_path / "run.npz").observe(right[4]).match_name == frame_name(stamps(6)[4])
    cv2.imwrite(str(tmp_path / "frame.png"), left[0])
    with pytest.raises(WilocError, match="topic: applies to ROS bags only"):
        Localizer(tmp_path, topic="/right", method="threshold")


@pytest.mark.parametrize("kind", KINDS)
def test_a_topic_without_messages_is_said_so(kind: str, tmp_path: Path, cache_dir: Path) -> None:
    path = tmp_path / ("empty.bag" if kind == "ros1" else "empty")
    writer = BagWriter(path, kind)
    writer.writer.add_connection("/cam", IMAGE, typestore=writer.store)  # a recorded topic that got no message
    writer.close()
    ends_in_one_error(runner.invoke(app, ["describe", str(path)]), 1, f"{path}: topic /cam holds no image message")


def test_a_missing_topic_lists_the_image_topics(tmp_path: Path, cache_dir: Path) -> None:
    bag = two_topics(tmp_path)
    ends_in_one_error(runner.invoke(app, ["describe", str(bag), "--topic", "/camera"]), 1,
                      f"{bag}: no topic /camera; its image topics: /left, /right")


def test_a_topic_of_another_type_is_refused(tmp_path: Path, cache_dir: Path) -> None:
    bag = two_topics(tmp_path)
    ends_in_one_error(runner.invoke(app, ["describe", str(bag), "--topic", "/odom"]), 1,
                      f"{bag}: topic /odom holds {ODOMETRY} messages, not {IMAGE} or {COMPRESSED}")


def test_several_image_topics_need_topic(tmp_path: Path, cache_dir: Path) -> None:
    bag = two_topics(tmp_path)
    ends_in_one_error(runner.invoke(app, ["describe", str(bag)]), 2,
                      f"--topic: {bag} has 2 image topics, give one: /left, /right")


@pytest.mark.parametrize("kind", ["ros1", "mcap", "sqlite3", "text"])
def test_a_truncated_or_corrupt_bag_is_one_line(kind: str, tmp_path: Path, cache_dir: Path) -> None:
    if kind == "text":
        bag = tmp_path / "notes.bag"
        bag.write_text("not a bag\n")
    else:
        bag = write_bag(tmp_path / "run", kind, scenes(10))
        file = bag if kind == "ros1" else next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
        file.write_bytes(file.read_bytes()[: file.stat().st_size // 2])
    ends_in_one_error(runner.invoke(app, ["describe", str(bag)]), 1, f"{bag}: cannot read this ROS bag")


def test_an_unsupported_encoding_is_one_line(tmp_path: Path, cache_dir: Path) -> None:
    writer = BagWriter(tmp_path / "run.bag", "ros1")
    writer.image("/cam", T0, scenes(1)[0], "yuv422")
    writer.close()
    ends_in_one_error(runner.invoke(app, ["describe", str(tmp_path / "run.bag")]), 1,
                      "topic /cam: image encoding 'yuv422' is not supported (supported: mono8, mono16, rgb8",
                      "bayer_rggb8")


def test_a_corrupt_compressed_frame_is_skipped(tmp_path: Path, cache_dir: Path) -> None:
    writer = BagWriter(tmp_path / "run.bag", "ros1")
    for i, stamp in enumerate(stamps(3)):
        data = cv2.imencode(".png", scenes(1, seed=i)[0])[1].tobytes()
        writer.compressed("/cam", stamp, data[: len(data) // 3] if i == 1 else data, "png")
    writer.close()
    result = runner.invoke(app, ["describe", str(tmp_path / "run.bag"), "--json"])
    assert result.exit_code == 0, result.output
    assert f"skipped {tmp_path / 'run.bag'}/{frame_name(stamps(3)[1])}: truncated PNG (no IEND chunk)" in result.stderr


def test_without_rosbags_the_extra_is_named(tmp_path: Path, cache_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    bag = write_bag(tmp_path / "run", "ros1", scenes(2))
    for module in [name for name in sys.modules if name == "rosbags" or name.startswith("rosbags.")]:
        monkeypatch.setitem(sys.modules, module, None)
    ends_in_one_error(runner.invoke(app, ["describe", str(bag)]), 2,
                      f'{bag}: reading ROS bags needs the rosbags package: pip install "wiloc[rosbags]"')


def test_topic_options_need_a_bag(tmp_path: Path, cache_dir: Path) -> None:
    folder = tmp_path / "ref"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), scenes(1)[0])
    ends_in_one_error(runner.invoke(app, ["describe", str(folder), "--topic", "/cam"]), 2,
                      "--topic: applies to ROS bags only")
    ends_in_one_error(runner.invoke(app, ["localize", str(folder), "--map", str(folder), "--method", "catgraph",
                                          "--odometry-topic", "/odom"]), 2, "--odometry-topic: applies to ROS bags only")


def test_an_odometry_topic_refused_is_named_as_given(tmp_path: Path, cache_dir: Path) -> None:
    """The bag's odometry came by --odometry-topic: a refusal names that option, not --odometry
    (a CSV the user never gave)."""
    bag = write_bag(tmp_path / "run", "ros1", scenes(6), odometry="/odom")
    ref = write_bag(tmp_path / "ref", "ros1", scenes(6), odometry="/odom")
    ends_in_one_error(runner.invoke(app, ["localize", str(bag), "--map", str(ref), "--method", "online",
                                          "--odometry-topic", "/odom"]), 2,
                      "error: --odometry-topic: method 'online' takes no odometry")
    ends_in_one_error(runner.invoke(app, ["localize", str(bag), "--method", "online", "--odometry-topic", "/odom"]),
                      2, "error: --odometry-topic: method 'online' takes no odometry")  # in sequence mode too
    folder = tmp_path / "folder"  # a map that is no bag has no odometry on the topic: refused before describing
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), scenes(1)[0])
    ends_in_one_error(runner.invoke(app, ["localize", str(bag), "--map", str(folder), "--method", "catgraph",
                                          "--odometry-topic", "/odom"]),
                      2, "error: --map-odometry: the map ", "is not a ROS bag: it has no odometry topic")
    assert not list(Path(cache_dir).rglob("*.h5"))
    with pytest.raises(WilocError) as refused:
        api.localize(bag, reference=ref, method="threshold", odometry_topic="/odom")
    assert refused.value.parameter == "odometry_topic"


def test_a_map_folder_with_an_odometry_topic_is_told_to_give_a_csv(tmp_path: Path, cache_dir: Path) -> None:
    """A query bag's topic against a map that is no bag: the refusal says the map has no topic,
    so its odometry comes as a CSV, not only that the map's is needed."""
    bag = write_bag(tmp_path / "run", "ros1", scenes(6), odometry="/odom")
    folder = tmp_path / "folder"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), scenes(1)[0])
    ends_in_one_error(runner.invoke(app, ["localize", str(bag), "--map", str(folder), "--method", "catgraph",
                                          "--odometry-topic", "/odom"]),
                      2, f"error: --map-odometry: the map {folder} is not a ROS bag: it has no odometry topic; "
                         "give its odometry as a CSV, in the units of the query's")
    assert not list(Path(cache_dir).rglob("*.h5"))


def test_a_bag_odometry_given_twice_names_the_topic_option(tmp_path: Path, cache_dir: Path) -> None:
    """A bag's odometry by --odometry-topic and as a CSV too: the refusal names the options as the
    command line spells them, not the Python API's odometry_topic."""
    bag = write_bag(tmp_path / "run", "ros1", scenes(6), odometry="/odom")
    ref = write_bag(tmp_path / "ref", "ros1", scenes(6), odometry="/odom")
    csv = tmp_path / "odometry.csv"
    csv.write_text("".join(f"{frame_name(s)},1\n" for s in stamps(6)))
    for option, flag, whose in (("--odometry", "--odometry-topic", "query"), ("--map-odometry", "--odometry-topic", "map")):
        result = runner.invoke(app, ["localize", str(bag), "--map", str(ref), "--method", "catgraph",
                                     "--odometry-topic", "/odom", option, str(csv)])
        ends_in_one_error(result, 2, f"error: {flag}: the {whose}'s bag gives its odometry on the topic; "
                                     "give it once, by the topic or as a CSV")
        assert "odometry_topic" not in result.stderr
    with pytest.raises(WilocError) as refused:
        api.localize(bag, reference=ref, method="catgraph", odometry_topic="/odom", odometry=csv)
    assert refused.value.parameter == "odometry_topic"


def odometry_bag(path: Path, images: list[np.ndarray], odometry: list[int]) -> Path:
    """A ROS 1 bag of `images` on /cam at 10 Hz from T0, and /odom messages at the stamps
    `odometry`, moving 1 m along x each."""
    writer = BagWriter(path, "ros1")
    for stamp, pixels in zip(stamps(len(images)), images):
        writer.image("/cam", stamp, pixels)
    for i, stamp in enumerate(odometry):
        writer.odometry("/odom", stamp, float(i), 0.0)
    writer.close()
    return path


def test_odometry_that_misses_frames_is_refused(tmp_path: Path, cache_dir: Path) -> None:
    """Frames outside the odometry's time span had their position held at its end (a robot
    standing still to the filter): refused as a CSV lacking them is, for the query's bag and the
    map's; a topic starting a few ms after the camera's first frame is normal and read."""
    images = scenes(10)  # frames T0 .. T0 + 0.9 s
    full = odometry_bag(tmp_path / "full.bag", images, [T0 + 5 * 10**6 + i * 50_000_000 for i in range(18)])
    with Bag(full) as opened:  # 5 ms late, ending 45 ms early: within the margin
        assert len(opened.arclength("/odom", [frame_name(s) for s in stamps(10)])) == 10
    half = odometry_bag(tmp_path / "half.bag", images, stamps(8, 50_000_000))  # to T0 + 0.35 s: frames 0-4
    late = odometry_bag(tmp_path / "late.bag", images, [T0 + 2 * 10**9 + i * 50_000_000 for i in range(10)])
    span = f"its messages span {frame_name(T0)} to {frame_name(T0 + 350_000_000)}"
    with Bag(half) as opened, pytest.raises(WilocError, match="topic /odom: no odometry for 5 frame") as refused:
        opened.arclength("/odom", [frame_name(s) for s in stamps(10)])  # frame 4, 50 ms after: within the margin
    assert f"first '{frame_name(T0 + 500_000_000)}'" in refused.value.problem and span in refused.value.problem
    for query, ref, bad, message in ((half, full, half, f"topic /odom: no odometry for 5 frame(s), first "
                                                        f"'{frame_name(T0 + 500_000_000)}': {span}"),
                                     (full, half, half, "topic /odom: no odometry for 5 frame(s)"),
                                     (late, full, late, "topic /odom: no odometry for any of its 10 frame(s)")):
        ends_in_one_error(runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "catgraph",
                                              "--odometry-topic", "/odom", "--out", str(tmp_path / "r.csv")]),
                          1, f"error: {bad}: {message}")
    ends_in_one_error(runner.invoke(app, ["localize", str(late), "--method", "catgraph", "--odometry-topic", "/odom",
                                          "-R", "2", "--frontier", "1", "--out", str(tmp_path / "r.csv")]),
                      1, f"error: {late}: topic /odom: no odometry for any")  # sequence mode: its own odometry
    run = api.localize(full, reference=full, method="catgraph", odometry_topic="/odom")
    assert len(run.decisions) == 10


# ------------------------------------------------------------------------------- Gardens Point

@pytest.mark.realdata
def test_gardens_point_bags_localize_as_the_folder_does(data_root: Path, tmp_path: Path) -> None:
    """day_left written into a ROS 1 bag and a ROS 2 MCAP bag, each with a raw topic (the pixels
    the folder's decode gives) and a compressed one (the JPEG bytes unchanged): catgraph against
    the day_right folder decides as with the day_left folder, on each topic of each bag."""
    root = data_root / "gardens-point-walking"
    files = sorted((root / "day_left").glob("*.jpg"))
    spec = get_descriptor("sad")  # catgraph's default descriptor
    bags = [BagWriter(tmp_path / "day_left.bag", "ros1"), BagWriter(tmp_path / "day_left", "mcap")]
    for stamp, file in zip(stamps(len(files)), files):
        pixels, data = read_gray(file, spec.min_size), file.read_bytes()
        for writer in bags:
            writer.image("/camera/image_raw", stamp, pixels)
            writer.compressed("/camera/image_raw/compressed", stamp, data, "jpeg")
    for writer in bags:
        writer.close()
    cache = Cache(tmp_path / "cache")
    folder = api.localize(root / "day_left", reference=root / "day_right", method="catgraph", cache=cache, jobs=1)
    for bag in (tmp_path / "day_left.bag", tmp_path / "day_left"):
        for topic in ("/camera/image_raw", "/camera/image_raw/compressed"):
            run = api.localize(bag, reference=root / "day_right", method="catgraph", cache=cache, jobs=1, topic=topic)
            assert run.results.frames["frame"].tolist() == [frame_name(s) for s in stamps(len(files))]
            for column in ("match", "decided", "confidence"):
                np.testing.assert_array_equal(getattr(run.decisions, column), getattr(folder.decisions, column))
