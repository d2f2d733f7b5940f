"""Traversal listing, fingerprints and grayscale reading (wiloc/sources/frames.py)."""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wiloc.errors import FrameError, WilocError
from wiloc.sources.frames import Fingerprint, fingerprint, jpeg_size, list_traversal, read_gray
from wiloc.sources.natural_order import natural_key, natural_sorted


def _write(path: Path, image: np.ndarray, ext: str | None = None) -> Path:
    ok, buf = cv2.imencode(ext or path.suffix, image)
    assert ok
    buf.tofile(path)
    return path


def _textured(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(0, 256, (h, w), dtype=np.uint8), (0, 0), 2)


def test_natural_key_orders_numbers_by_value() -> None:
    names = ["img10.png", "img2.png", "img1.png", "Img3.png", "img2b.png"]
    assert sorted(names, key=natural_key) == [
        "img1.png", "img2.png", "img2b.png", "Img3.png", "img10.png"
    ]
    # a name that is the start of another comes first, whatever the case of the rest
    assert sorted(["frame10", "frame", "Frame1", "frame2"], key=natural_key) == ["frame", "Frame1", "frame2", "frame10"]


def test_natural_key_orders_decimal_fractions_as_fractions() -> None:
    # timestamps written as floats (Python's str, ROS's to_sec()) drop trailing zeros: a fraction's
    # digits are read as a fraction, as time goes, where natural order put .2 before .15
    rng = np.random.default_rng(3)
    stamps = [float(t) for t in np.round(1614000000 + np.cumsum(rng.uniform(0.01, 0.3, 60)), 6)]
    names = [f"{t}.jpg" for t in stamps]
    assert len({len(name) for name in names}) > 2  # fractions of different lengths
    assert sorted(names[::-1], key=natural_key) == names  # noqa: C415 - sorted from the reverse order
    # dotted runs that are no decimal number (dates, versions) keep each run's value
    assert sorted(["v2021.3.15.png", "v2021.3.9.png"], key=natural_key) == ["v2021.3.9.png", "v2021.3.15.png"]
    assert sorted(["frame.10.png", "frame.2.png"], key=natural_key) == ["frame.2.png", "frame.10.png"]


def test_numbering_written_with_dots_keeps_its_order(tmp_path: Path) -> None:
    """``scene1.10`` read as the decimal 1.1 came before ``scene1.9``: names that differ only by a
    fraction's trailing zeros (``scene1.1``, ``scene1.10``) are numbering, which a decimal's
    writing never gives, so the whole folder keeps each dotted run's value; timestamps stay in
    time order."""
    numbered = [f"scene{s}.{k}.png" for s in (1, 2) for k in range(1, 13)]
    assert natural_sorted(numbered[::-1]) == numbered
    every_fifth = [f"scene1.{k}.png" for k in range(5, 60, 5)]  # 1.5 and 1.50
    assert natural_sorted(every_fifth[::-1]) == every_fifth
    for name in numbered[:12]:
        cv2.imwrite(str(tmp_path / name), _textured(8, 8))
    assert list(list_traversal(tmp_path).frame_names) == numbered[:12]
    stamps = ["1614000000.1.jpg", "1614000000.15.jpg", "1614000000.2.jpg", "1614000001.05.jpg"]
    assert natural_sorted(stamps[::-1]) == stamps


def test_a_folder_of_sub_folders_names_them(tmp_path: Path) -> None:
    # datasets keep each camera's images in a folder of its own (EuRoC's cam0/data, KITTI's
    # image_0): given their parent, the error says the sub-folders were not searched, and which
    for camera in ("cam1", "cam0"):
        (tmp_path / camera / "data").mkdir(parents=True)
        cv2.imwrite(str(tmp_path / camera / "data" / "0.png"), _textured(8, 8))
    (tmp_path / ".git").mkdir()
    with pytest.raises(WilocError, match=r"no image files .*; sub-folders are not searched: give the one holding "
                                         r"the images \(cam0, cam1\)$"):
        list_traversal(tmp_path)
    with pytest.raises(WilocError, match=r"no image files \([^)]*\)$"):
        list_traversal(tmp_path / ".git")


def test_list_traversal_orders_float_timestamps_in_time_order(tmp_path: Path) -> None:
    # a whole second written with its fraction's zeros and point dropped (1614000001) is x.0: it
    # came after every fraction of its second, 1614000001.05 before 1614000001
    for name in ("1614000000.2.png", "1614000000.15.png", "1614000000.1.png", "1614000001.05.png",
                 "1614000001.png", "1614000000.png", "1614000002.png"):
        (tmp_path / name).write_bytes(b"x")
    names = list_traversal(tmp_path).names
    assert names == sorted(names, key=lambda name: float(name.removesuffix(".png")))


_NAME = st.text(alphabet="aAb_.-é0123456789", min_size=1, max_size=8)


@settings(max_examples=300, deadline=None)
@given(names=st.lists(_NAME, max_size=12), template=_NAME, numbers=st.lists(st.integers(0, 10**5), max_size=12),
       width=st.integers(1, 6))
def test_natural_sorted_is_the_natural_keys_order(names: list[str], template: str, numbers: list[int],
                                                  width: int) -> None:
    # numbered names (the template with each digit run replaced by one zero-padded number) take
    # the shortcut when their digit runs are equally long; any other mix takes natsort's keys
    numbered = ["".join(f"{n:0{width}d}" if c.isdigit() else c for c in template) for n in numbers]
    for listed in (names, numbered, numbered + names):
        assert natural_sorted(listed) == sorted(listed, key=natural_key)


def test_list_traversal_natural_order_and_ignored(tmp_path: Path) -> None:
    for i in (10, 2, 1):
        _write(tmp_path / f"img{i}.png", _textured(8, 8, i))
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / ".hidden.png").write_bytes(b"")
    (tmp_path / "UPPER.JPG").write_bytes(b"")
    (tmp_path / "sub.png").mkdir()
    trav = list_traversal(tmp_path)
    assert trav.names == ["img1.png", "img2.png", "img10.png", "UPPER.JPG"]
    assert {p.name for p in trav.ignored} == {"notes.txt", ".hidden.png", "sub.png"}


def test_a_symbolic_link_loop_is_called_one_not_a_broken_link(tmp_path: Path) -> None:
    """A link to itself and a link to nowhere are both names no stat can follow; the skipped line
    says which, since the fix differs (remove the loop; restore or remove the link's target)."""
    (tmp_path / "img1.png").write_bytes(b"")
    (tmp_path / "loop.jpg").symlink_to("loop.jpg")
    (tmp_path / "gone.jpg").symlink_to("nowhere.jpg")
    os.mkfifo(tmp_path / "pipe")
    (tmp_path / "piped.png").symlink_to("pipe")
    trav = list_traversal(tmp_path)
    assert trav.names == ["img1.png"]
    assert dict(trav.unusable) == {"loop.jpg": "symbolic link loop", "gone.jpg": "broken symbolic link",
                                   "piped.png": "not a regular file"}

def test_images_of_other_formats_are_named_as_left_out_and_jpeg_under_its_other_names_is_read(tmp_path: Path) -> None:
    """A JPEG named .jfif or .jpe is a frame; a JPEG 2000 or GIF file is no frame, and is listed
    with the reason (a line on stderr), not ignored unnoticed as a README is."""
    for name in ("img1.jpg", "img2.jfif", "img3.JPE", "img4.jp2", "img5.gif", "README.txt"):
        (tmp_path / name).write_bytes(b"")
    trav = list_traversal(tmp_path)
    assert trav.names == ["img1.jpg", "img2.jfif", "img3.JPE"]
    assert [name for name, _ in trav.unusable] == ["img4.jp2", "img5.gif"]
    assert all(reason.startswith("an image format that is no frame here") for _, reason in trav.unusable)
    assert [p.name for p in trav.ignored] == ["README.txt"]


def test_list_traversal_lists_names_and_makes_paths_in_natural_order(tmp_path: Path) -> None:
    names = ["img10.jpg", "img9.jpg", "IMG9.jpg", "img09.jpg", "img9a.jpg", "b.png", "A.png", "ä1.png",
             "x2y10.png", "x2y9.png", "x10y1.png", "10.png", "9.png", "z.JPEG"]
    for name in names:
        (tmp_path / name).write_bytes(b"")
    trav = list_traversal(tmp_path)
    assert trav.names == sorted(names, key=natural_key)
    assert trav.names[:5] == ["9.png", "10.png", "A.png", "ä1.png", "b.png"]  # ä as a with its accent
    assert trav.frames == tuple(tmp_path / name for name in trav.names)
    assert trav.frame_names == tuple(trav.names)


@pytest.mark.parametrize("make", ["missing", "file", "empty", "only-text"])
def test_list_traversal_errors_name_the_folder(tmp_path: Path, make: str) -> None:
    folder = tmp_path / "trav"
    if make == "file":
        folder.write_text("x")
    elif make in ("empty", "only-text"):
        folder.mkdir()
        if make == "only-text":
            (folder / "a.txt").write_text("x")
    with pytest.raises(WilocError) as err:
        list_traversal(folder)
    assert err.value.where == str(folder)


def test_fingerprint_matches_content(tmp_path: Path) -> None:
    path = tmp_path / "a.bin"
    path.write_bytes(b"hello wiloc")
    fp = fingerprint(path)
    assert isinstance(fp, Fingerprint)
    assert fp.size == 11
    assert fp.digest == hashlib.blake2b(b"hello wiloc", digest_size=16).hexdigest()
    path.write_bytes(b"hello wilod")
    assert fingerprint(path).digest != fp.digest


def test_read_unicode_name(tmp_path: Path) -> None:
    image = _textured(20, 30)
    path = _write(tmp_path / "Straße_夜_01.png", image)
    assert np.array_equal(read_gray(path), image)


def test_read_grayscale_png_passes_unchanged(tmp_path: Path) -> None:
    image = _textured(17, 23)
    out = read_gray(_write(tmp_path / "g.png", image))
    assert out.dtype == np.uint8 and np.array_equal(out, image)


def test_read_16bit_png_is_scaled_not_truncated(tmp_path: Path) -> None:
    values = np.linspace(0, 65535, 64 * 16).astype(np.uint16).reshape(16, 64)
    out = read_gray(_write(tmp_path / "deep.png", values))
    expected = np.rint(values.astype(np.float64) * 255 / 65535)
    assert out.dtype == np.uint8
    assert np.abs(out.astype(np.float64) - expected).max() <= 1
    assert out.max() == 255 and out.min() == 0


def test_read_rgba_png_drops_alpha(tmp_path: Path) -> None:
    bgr = np.dstack([_textured(12, 12, s) for s in (1, 2, 3)])
    alpha = np.zeros((12, 12), np.uint8)  # fully transparent must not blank the image
    out = read_gray(_write(tmp_path / "rgba.png", np.dstack([bgr, alpha])))
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(int)
    assert out.shape == (12, 12)
    assert np.abs(out.astype(int) - expected).max() <= 1  # libpng's own luma rounding


def test_read_zero_byte_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.jpg"
    path.write_bytes(b"")
    with pytest.raises(FrameError, match="empty") as err:
        read_gray(path)
    assert err.value.where == str(path)


def test_read_truncated_jpeg(tmp_path: Path) -> None:
    path = _write(tmp_path / "full.jpg", _textured(64, 64))
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(FrameError, match="truncated") as err:
        read_gray(cut)
    assert err.value.where == str(cut)


def test_read_jpeg_with_zero_padding_after_eoi(tmp_path: Path) -> None:
    path = _write(tmp_path / "padded.jpg", _textured(32, 32))
    path.write_bytes(path.read_bytes() + b"\x00" * 16)
    assert read_gray(path).shape == (32, 32)


# A phone-style trailer after EOI (Samsung's starts "SEFH"): several KB not ending in FF D9.
_TRAILER = b"SEFH" + bytes(range(256)) * 24 + b"SEFT"


@pytest.mark.parametrize("params", [[], [cv2.IMWRITE_JPEG_PROGRESSIVE, 1],
                                    [cv2.IMWRITE_JPEG_RST_INTERVAL, 2]])
def test_read_jpeg_with_trailer_after_eoi(tmp_path: Path, params: list[int]) -> None:
    image = _textured(64, 96)
    ok, buf = cv2.imencode(".jpg", image, params)
    assert ok
    whole = buf.tobytes()
    phone = tmp_path / "phone.jpg"
    phone.write_bytes(whole + _TRAILER)
    assert len(_TRAILER) > 4096
    assert np.array_equal(read_gray(phone), cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE))
    assert read_gray(phone, (24, 16)).shape == (16, 24)
    cut = tmp_path / "cut.jpg"
    for end in (len(whole) - 2, len(whole) // 2, len(whole) // 10):
        cut.write_bytes(whole[:end])
        with pytest.raises(FrameError, match="truncated"):
            read_gray(cut)
        cut.write_bytes(whole[:end] + b"\x00" * 64)  # zero padding does not hide the cut
        with pytest.raises(FrameError, match="truncated"):
            read_gray(cut)


def test_fill_bytes_before_a_jpeg_marker_are_read_past(tmp_path: Path) -> None:
    ok, buf = cv2.imencode(".jpg", _textured(32, 48))
    assert ok
    whole = buf.tobytes()
    path = tmp_path / "filled.jpg"
    path.write_bytes(whole[:-2] + b"\xff" * 5 + whole[-2:])  # FF fill bytes are allowed before any marker
    assert np.array_equal(read_gray(path), cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE))
    path.write_bytes(whole[:-2] + b"\xff" * 5)
    with pytest.raises(FrameError, match="truncated JPEG"):
        read_gray(path)


@pytest.mark.parametrize("side", [16, 400])  # one IDAT chunk, and many (OpenCV writes them 8 KB each)
def test_a_png_cut_short_is_refused_and_one_with_bytes_after_iend_read(tmp_path: Path, side: int) -> None:
    ok, buf = cv2.imencode(".png", _textured(side, side))
    assert ok
    whole = buf.tobytes()
    path = tmp_path / "frame.png"
    for end in (len(whole) - 1, len(whole) - 12, len(whole) // 2, 40):
        path.write_bytes(whole[:end])
        with pytest.raises(FrameError, match="truncated PNG") as err:
            read_gray(path)
        assert err.value.where == str(path)
    for end in (len(whole) - 12, len(whole) // 2, 40):  # zero padding does not hide a cut before IEND
        path.write_bytes(whole[:end] + b"\x00" * 64)
        with pytest.raises(FrameError, match="truncated PNG"):
            read_gray(path)
    path.write_bytes(whole + b"\x00" * 64 + b"IEND")  # what follows IEND is not looked at
    assert np.array_equal(read_gray(path), cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE))


def test_thumbnail_eoi_does_not_hide_a_cut_jpeg(tmp_path: Path) -> None:
    ok, thumb = cv2.imencode(".jpg", _textured(8, 8, 1))
    ok2, main = cv2.imencode(".jpg", _textured(64, 64, 2))
    assert ok and ok2
    payload = b"Exif\x00\x00" + thumb.tobytes()  # an APP1 segment holding a whole JPEG
    app1 = b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload
    whole = main.tobytes()[:2] + app1 + main.tobytes()[2:]
    path = tmp_path / "exif.jpg"
    path.write_bytes(whole)
    assert read_gray(path).shape == (64, 64)
    path.write_bytes(whole[: len(whole) - 200])
    with pytest.raises(FrameError, match="truncated"):
        read_gray(path)


def test_read_undecodable_data(tmp_path: Path) -> None:
    path = tmp_path / "junk.png"
    path.write_bytes(b"this is not an image at all")
    with pytest.raises(FrameError, match="decode"):
        read_gray(path)


@pytest.mark.parametrize("min_size", [(100, 50), (200, 150), (401, 10), (800, 600)])
def test_reduced_decode_keeps_min_size(tmp_path: Path, min_size: tuple[int, int]) -> None:
    path = _write(tmp_path / "big.jpg", _textured(600, 800))
    assert jpeg_size(np.fromfile(path, np.uint8)) == (800, 600)
    out = read_gray(path, min_size)
    assert out.shape[1] >= min_size[0] and out.shape[0] >= min_size[1]
    factor = 800 // out.shape[1]
    assert factor in (1, 2, 4, 8)
    if factor < 8:  # the next reduction would have been too small
        assert -(-800 // (2 * factor)) < min_size[0] or -(-600 // (2 * factor)) < min_size[1]


def test_reduced_decode_of_small_image_is_full(tmp_path: Path) -> None:
    path = _write(tmp_path / "small.jpg", _textured(30, 40))
    assert read_gray(path, (256, 256)).shape == (30, 40)


def _tiff(pages: list[tuple[np.ndarray, int]], big: bool = False) -> bytes:
    """A little-endian uncompressed 8-bit TIFF (BigTIFF with ``big``) of ``pages``, each an image
    and its NewSubfileType (1: a reduced-resolution image, a thumbnail)."""
    import struct

    offset, count, entry = ("Q", "Q", "<HHQQ") if big else ("I", "H", "<HHII")
    out = bytearray(b"II+\x00\x08\x00\x00\x00" + bytes(8) if big else b"II*\x00" + bytes(4))
    link = len(out) - struct.calcsize(offset)  # where the next directory's offset goes
    for image, kind in pages:
        strip = len(out)
        out += image.tobytes()
        tags = [(254, 4, kind), (256, 4, image.shape[1]), (257, 4, image.shape[0]), (258, 3, 8), (259, 3, 1),
                (262, 3, 1), (273, 4, strip), (277, 3, 1), (278, 4, image.shape[0]), (279, 4, image.size)]
        struct.pack_into("<" + offset, out, link, len(out))
        out += struct.pack("<" + count, len(tags)) + b"".join(struct.pack(entry, t, k, 1, v) for t, k, v in tags)
        link = len(out)
        out += bytes(struct.calcsize(offset))
    return bytes(out)


@pytest.mark.parametrize("big", [False, True])
def test_a_tiff_of_several_pages_is_refused_and_its_thumbnail_read_past(big: bool, tmp_path: Path) -> None:
    """OpenCV decodes a TIFF's first page alone: a stack of frames in one file was read as its
    first frame, silently. A thumbnail after the image (a reduced-resolution page) is no page."""
    image, other = _textured(32, 48, 1), _textured(32, 48, 2)
    stack = tmp_path / "stack.tif"
    stack.write_bytes(_tiff([(image, 0), (other, 0), (image, 0)], big))
    with pytest.raises(FrameError, match="a TIFF of 3 pages: .* write each page to a file of its own"):
        read_gray(stack)
    one = tmp_path / "one.tif"
    one.write_bytes(_tiff([(image, 0), (other[::4, ::4].copy(), 1)], big))
    assert np.array_equal(read_gray(one), image)


@pytest.mark.parametrize("dtype", [np.float32, np.int32])
def test_a_tiff_of_float_or_32_bit_samples_says_what_to_save(dtype: type, tmp_path: Path) -> None:
    path = tmp_path / "frame.tif"
    assert cv2.imwrite(str(path), _textured(16, 16).astype(dtype))
    with pytest.raises(FrameError, match=f"unsupported sample type {np.dtype(dtype)}: .*save .* as 16-bit"):
        read_gray(path)
