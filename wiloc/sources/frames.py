"""Traversal folders: listing frames in natural order (``natural_order``), fingerprints, and reading grayscale images.

A frame is identified by its file name. ``read_gray`` decodes with OpenCV from bytes read by
numpy (so non-ASCII names work) and, for JPEGs, uses libjpeg's reduced (DCT-scaled) decode when
the caller says how small a decode it can use; see docs/descriptors.md for the measurements
behind each descriptor's ``min_size``.
"""
from __future__ import annotations

import errno
import hashlib
import math
import os
import re
import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from wiloc.errors import FrameError, WilocError, shown_name
from wiloc.sources.natural_order import natural_key, natural_sorted

IMAGE_SUFFIXES: frozenset[str] = frozenset(
    {".jpg", ".jpeg", ".jpe", ".jfif", ".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".pbm", ".pnm", ".webp"}
)

#: Suffixes of image formats that are no frames here (JPEG 2000, GIF, HEIF, AVIF, HDR, camera raw):
#: a file with one is named as left out, since leaving it out unnoticed would shift every later
#: frame's position (and ground truth by position with it).
OTHER_IMAGE_SUFFIXES: frozenset[str] = frozenset(
    {".jp2", ".j2k", ".jpf", ".jpx", ".gif", ".heic", ".heif", ".avif", ".exr", ".hdr", ".pic", ".sr", ".ras",
     ".dng", ".cr2", ".nef", ".arw", ".raw"}
)

# A JPEG marker: FF, then a code that is neither byte stuffing (00), a restart marker (D0-D7,
# inside entropy-coded data) nor a fill byte (FF: the marker starts at the last one). Without a
# repeat for the fill bytes, the search over entropy-coded data runs a fifth faster.
_MARKER = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")
_EOI = 0xD9
_SOI = b"\xff\xd8"  # a JPEG's start-of-image marker, its first two bytes
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_IEND_CHUNK = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # length 0, type, CRC: the chunk a PNG ends with
# TIFF's byte-order marks and magic numbers -> (struct byte order, offset width): classic, BigTIFF.
_TIFF_HEADS = {b"II*\x00": ("<", 4), b"MM\x00*": (">", 4), b"II+\x00": ("<", 8), b"MM\x00+": (">", 8)}
_NEW_SUBFILE_TYPE = 254  # its bits 0 and 2: a reduced-resolution image (a thumbnail), a transparency mask
_STANDALONE = frozenset({0x01, 0xD8})  # TEM and SOI: markers without a length field
_SOS = 0xDA
_SEQUENTIAL_SOF = frozenset({0xC0, 0xC1})  # baseline and extended sequential (Huffman) frames
_REDUCED_FLAGS = (
    (8, cv2.IMREAD_REDUCED_GRAYSCALE_8),
    (4, cv2.IMREAD_REDUCED_GRAYSCALE_4),
    (2, cv2.IMREAD_REDUCED_GRAYSCALE_2),
)
# JPEG start-of-frame markers: C0-CF except DHT (C4), JPG (C8) and DAC (CC).
_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: Largest ratio of an image's long side to its short one. Descriptors that cover a square and
#: crop it (gist, an onnx network's ``crop``) scale the long side by as much: a 1 x 100000 strip
#: would take 26 GB; at this ratio gist's intermediate image is 64 MB.
MAX_ASPECT = 256
@dataclass(frozen=True)
class Traversal:
    """One traversal folder: its image files in natural order, and the files that were skipped.
    Frames are held by name and their paths made on first use: checking a folder against the
    cache needs names only, and a Path per frame cost as much as the listing itself."""

    folder: Path
    frame_names: tuple[str, ...]
    ignored: tuple[Path, ...]
    unusable: tuple[tuple[str, str], ...] = ()  # image names left out: (name as shown, why)

    @cached_property
    def frames(self) -> tuple[Path, ...]:
        """The image files, in natural order."""
        return tuple(self.folder / name for name in self.frame_names)

    @property
    def names(self) -> list[str]:
        """Frame names (file names), the identifiers used everywhere."""
        return list(self.frame_names)


def text_path(path: Path) -> str:
    """``path`` resolved, as the text the cache and results files record it by; a WilocError
    naming it when it is not valid UTF-8 (a folder or file name in it holds other bytes)."""
    resolved = str(Path(path).resolve())
    if shown_name(resolved) != resolved:
        raise WilocError(path, "path is not valid UTF-8 (the cache and results files record paths as "
                               "UTF-8 text); rename it to use it")
    return resolved


def unusable_reason(item: os.DirEntry[str] | Path) -> str | None:
    """Why a file named as an image cannot be a frame, or None when it can: a name that is not
    UTF-8 (results files and the cache hold names as UTF-8 text), a broken symbolic link or one
    that loops (each needs its own fix), or not a regular file (a FIFO would block the reader)."""
    if shown_name(item.name) != item.name:
        return "file name is not valid UTF-8; rename the file to use it"
    if type_test(item.is_file):
        return None
    if item.is_symlink():
        try:
            os.stat(item)
        except OSError as exc:
            return "symbolic link loop" if exc.errno == errno.ELOOP else "broken symbolic link"
    return "not a regular file"


def type_test(test: Callable[[], bool]) -> bool:
    """A directory entry's type test (``entry.is_dir``), False where following its link fails (a
    link that loops: a path's test says False there, a ``DirEntry``'s raises)."""
    try:
        return test()
    except OSError:
        return False


def not_a_traversal(path: Path, takes: str) -> str:
    """Why the file at ``path``, given where a traversal goes, is none, saying what it is (a wiloc
    results file, an image file, a .txt file) and, in ``takes``, what the command takes instead."""
    from wiloc.evaluation.results_header import starts_as_results  # a later module: read only here

    suffix = Path(path).suffix.lower()
    kind = ("a wiloc results file" if starts_as_results(path) else "an image file" if suffix in IMAGE_SUFFIXES
            else f"a {suffix} file" if suffix else "a file without a suffix")
    hint = "; evaluate and compare read results files" if kind == "a wiloc results file" else ""
    return f"{kind} is not a traversal: {takes}{hint}"


def list_traversal(folder: Path) -> Traversal:
    """List a traversal folder: image files in natural order; hidden and non-image files and
    subfolders (not searched) ignored, image names that cannot be frames (:func:`unusable_reason`,
    :data:`OTHER_IMAGE_SUFFIXES`) listed with the reason."""
    if not (folder := Path(folder)).exists():  # a missing x.h5, x.npy, x.mp4, x.jpg: a file given, said so
        from wiloc.description.traversals import MATRIX_SUFFIXES, is_bag, is_video  # later modules: read only here
        named = is_video(folder) or is_bag(folder) or folder.suffix.lower() in MATRIX_SUFFIXES | IMAGE_SUFFIXES
        raise WilocError(folder, f"{'file' if named else 'folder'} does not exist")
    if folder.is_file():
        raise WilocError(folder, not_a_traversal(folder, "give a folder of images"))
    if not folder.is_dir():
        raise WilocError(folder, "not a folder")
    frames: list[str] = []
    ignored: list[str] = []
    subfolders: list[str] = []
    unusable: list[tuple[str, str]] = []
    with os.scandir(folder) as entries:  # the entries know their type: no stat per file
        for item in entries:
            suffix, is_dir = os.path.splitext(item.name)[1].lower(), type_test(item.is_dir)
            if is_dir and not item.name.startswith("."):
                subfolders.append(shown_name(item.name))
            if (item.name.startswith(".") or (suffix not in IMAGE_SUFFIXES and suffix not in OTHER_IMAGE_SUFFIXES)
                    or is_dir):
                ignored.append(shown_name(item.name))
            elif suffix in OTHER_IMAGE_SUFFIXES:
                unusable.append((shown_name(item.name), f"an image format that is no frame here (frames are "
                                                        f"{' '.join(sorted(IMAGE_SUFFIXES))}: convert it)"))
            elif (reason := unusable_reason(item)) is not None:
                unusable.append((shown_name(item.name), reason))
            else:
                frames.append(item.name)
    if unusable and not frames:
        name, reason = unusable[0]
        raise WilocError(folder, f"no usable image files ({name}: {reason}"
                                 f"{f'; {len(unusable) - 1} more' if len(unusable) > 1 else ''})")
    if not frames:
        raise WilocError(folder, f"no image files ({', '.join(sorted(IMAGE_SUFFIXES))})"
                                 + (f"; {subfolders_hint(subfolders)}" if subfolders else ""))
    return Traversal(folder=folder, frame_names=tuple(natural_sorted(frames)),
                     ignored=tuple(folder / name for name in natural_sorted(ignored)),
                     unusable=tuple(sorted(unusable, key=lambda u: natural_key(u[0]))))


def subfolders_hint(subfolders: Iterable[str]) -> str:
    """What to say of a folder without images that holds ``subfolders`` (a camera's parent)."""
    names = natural_sorted(subfolders)
    shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
    return f"sub-folders are not searched: give the one holding the images ({shown})"


@dataclass(frozen=True)
class Fingerprint:
    """What identifies a frame file's content: size, modification time and a content digest."""

    size: int
    mtime_ns: int
    digest: str


def fingerprint(path: Path) -> Fingerprint:
    """Size, mtime and blake2b-128 hex digest of a file's content (for cache validation)."""
    path = Path(path)
    stat = path.stat()
    digest = hashlib.blake2b(digest_size=16)
    with path.open("rb") as handle:  # in blocks (hashlib.file_digest is Python 3.11's)
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return Fingerprint(size=stat.st_size, mtime_ns=stat.st_mtime_ns, digest=digest.hexdigest())


def jpeg_size(data: NDArray[np.uint8]) -> tuple[int, int] | None:
    """(width, height) from a JPEG's start-of-frame header, or None if no SOF is found."""
    raw = data.tobytes() if data.size < 65536 else data[:65536].tobytes()
    pos = 2
    while pos + 9 < len(raw):
        if raw[pos] != 0xFF:
            return None
        marker = raw[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in _SOF_MARKERS:
            height = int.from_bytes(raw[pos + 5 : pos + 7], "big")
            width = int.from_bytes(raw[pos + 7 : pos + 9], "big")
            return width, height
        pos += 2 + int.from_bytes(raw[pos + 2 : pos + 4], "big")
    return None


def _has_eoi(data: NDArray[np.uint8]) -> bool:
    """Whether a JPEG's marker chain reaches its end-of-image marker (EOI, FF D9).

    Segments are skipped by their length (so an EXIF thumbnail's own EOI is never taken for the
    image's) and entropy-coded data up to its next marker; whatever follows the EOI (zero
    padding, the trailers some phones append) is not looked at. A cut file runs out first.
    A sequential frame's scan of all its components is its only one, and entropy-coded data
    holds no FF D9: such a file is whole when an FF D9 follows the scan's header anywhere,
    which a search from the file's end finds without reading the scan (7 us instead of 40 on
    a Gardens Point frame; progressive and other frames are walked through).
    """
    raw = data.tobytes()  # indexed and searched a few times faster than the array's memoryview
    pos = 2
    components = 0  # of a sequential frame
    while (match := _MARKER.search(raw, pos)) is not None:
        pos = match.end()
        code = raw[pos - 1]
        if code == _EOI:
            return True
        if code in _STANDALONE:
            continue
        if pos + 3 > len(raw):
            return False
        length = raw[pos] << 8 | raw[pos + 1]
        if code in _SEQUENTIAL_SOF and pos + 8 <= len(raw):
            components = raw[pos + 7]
        elif code == _SOS and components and raw[pos + 2] == components:
            return raw.rfind(b"\xff\xd9") >= pos + length
        pos += length
    return False


def _has_iend(data: NDArray[np.uint8]) -> bool:
    """Whether a PNG's chunk chain reaches its IEND chunk, whole.

    The chunks (length, type, data, CRC) are walked by their length, so that bytes appended
    after IEND are not looked at. A cut file runs out first, whatever the decoder OpenCV was
    built with makes of it. (:func:`_checked` takes a file ending on the IEND chunk, CRC
    included, as whole without the walk: a cut lands there by a 2^-96 chance.)
    """
    pos = len(_PNG_SIGNATURE)
    while pos + len(_IEND_CHUNK) <= data.size:
        length_and_type = data[pos : pos + 8].tobytes()
        if length_and_type[4:] == b"IEND":
            return True
        pos += len(_IEND_CHUNK) + int.from_bytes(length_and_type[:4], "big")
    return False


#: How many bytes of a file :func:`end_checked` needs to tell its format.
FORMAT_HEAD_BYTES = len(_PNG_SIGNATURE)


def end_checked(head: bytes) -> bool:
    """Whether an encoded image whose first :data:`FORMAT_HEAD_BYTES` bytes are ``head`` is of a
    format whose end the reader checks (a JPEG, a PNG: :func:`_checked`): cut short, it is refused
    with a FrameError rather than decoded in part, so it may be read while its writer may not be
    done. Other formats (BMP, TIFF, ...) may decode cut short, their missing part made up."""
    return head[:2] == _SOI or head[: len(_PNG_SIGNATURE)] == _PNG_SIGNATURE


def _reduction(full: tuple[int, int], min_size: tuple[int, int]) -> int:
    """Largest JPEG reduction (1, 2, 4, 8) whose decode keeps both sides >= min_size."""
    for factor, _ in _REDUCED_FLAGS:
        if all(math.ceil(side / factor) >= need for side, need in zip(full, min_size)):
            return factor
    return 1


def to_uint8(image: NDArray, path: Path | str) -> NDArray[np.uint8]:
    """8-bit single-channel image: 16-bit samples scaled by 255/65535, not truncated."""
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.uint16:
        return np.rint(image.astype(np.float32) * np.float32(255.0 / 65535.0)).astype(np.uint8)
    raise FrameError(path, f"unsupported sample type {image.dtype}: frames are read as 8- or 16-bit integers "
                           "(save float or 32-bit frames as 16-bit, scaled to its full range)")


def check_aspect(image: NDArray, where: Path | str) -> NDArray:
    """``image`` (H x W, or H x W x C), or a FrameError naming ``where`` when one side is over
    :data:`MAX_ASPECT` times the other: no descriptor can describe it in bounded memory."""
    height, width = image.shape[:2]
    if max(height, width) > MAX_ASPECT * min(height, width):
        raise FrameError(where, f"image of {width} x {height} pixels: one side is over {MAX_ASPECT} times the other")
    return image


def _over_limit(path: Path | str) -> FrameError:
    return FrameError(path, "image over OpenCV's size limit (2^30 pixels; the environment variable "
                            "OPENCV_IO_MAX_IMAGE_PIXELS raises it)")


def _max_pixels() -> int:
    """OpenCV's decode limit in pixels: OPENCV_IO_MAX_IMAGE_PIXELS, else 2^30."""
    value = os.environ.get("OPENCV_IO_MAX_IMAGE_PIXELS", "")
    return int(value) if value.isdigit() else 1 << 30


def decode(data: NDArray[np.uint8], flags: int, path: Path | str) -> NDArray | None:
    """``cv2.imdecode``, with OpenCV's own refusals (an image over its pixel limit, a broken
    header it asserts on) raised as FrameError naming the file; None when it cannot decode."""
    try:
        return cv2.imdecode(data, flags)
    except cv2.error as exc:
        if "CV_IO_MAX_IMAGE_PIXELS" in str(exc):
            raise _over_limit(path) from None
        raise FrameError(path, f"cannot decode image data ({exc.err or 'OpenCV refused it'})") from None


def _file_bytes(path: Path) -> NDArray[np.uint8]:
    """An image file's bytes, read with numpy; FrameError for an unreadable file."""
    try:
        return np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise FrameError(path, f"cannot read file ({exc.strerror or exc})") from exc


def tiff_pages(data: NDArray[np.uint8]) -> int:
    """How many full-resolution images a TIFF holds: its chain of image directories, thumbnails
    and masks (``NewSubfileType``) not counted; 0 for another format or a chain cut short there."""
    layout = _TIFF_HEADS.get(data[:4].tobytes())
    if layout is None:
        return 0
    order, width = layout
    offset_format, count_format, entry, value_at = ("Q", "Q", 20, 12) if width == 8 else ("I", "H", 12, 8)
    pages, seen = 0, set()
    try:
        offset = struct.unpack_from(order + offset_format, data, width)[0]  # after the magic (BigTIFF's: 4 bytes more)
        while offset and offset not in seen:
            seen.add(offset)
            count = struct.unpack_from(order + count_format, data, offset)[0]
            first = offset + struct.calcsize(count_format)
            kind = 0
            for at in range(first, first + count * entry, entry):
                tag, typ = struct.unpack_from(order + "HH", data, at)
                if tag == _NEW_SUBFILE_TYPE:
                    kind = struct.unpack_from(order + ("H" if typ == 3 else "I"), data, at + value_at)[0]
            pages += kind & 0b101 == 0
            offset = struct.unpack_from(order + offset_format, data, first + count * entry)[0]
    except struct.error:  # a directory past the file's end: the pages counted so far
        pass
    return pages


def _checked(data: NDArray[np.uint8], path: Path | str) -> NDArray[np.uint8]:
    """``data``, an encoded image; FrameError naming ``path`` when it is empty, a JPEG or PNG
    cut short (OpenCV 4.8 and 4.10 decode a cut JPEG as a whole image, its missing part filled in),
    or a TIFF of several pages (OpenCV decodes its first page alone: a stack of frames is no frame)."""
    if data.size == 0:
        raise FrameError(path, "empty file (0 bytes)")
    if (pages := tiff_pages(data)) > 1:
        raise FrameError(path, f"a TIFF of {pages} pages: a frame is one image per file, and this one would be "
                               "its first page alone; write each page to a file of its own")
    head = data[: len(_PNG_SIGNATURE)].tobytes()
    if head[:2] == _SOI:
        if not _has_eoi(data):
            raise FrameError(path, "truncated JPEG (no end-of-image marker)")
    elif head == _PNG_SIGNATURE and data[-len(_IEND_CHUNK):].tobytes() != _IEND_CHUNK and not _has_iend(data):
        raise FrameError(path, "truncated PNG (no IEND chunk)")
    return data


def read_colour(path: Path) -> NDArray[np.uint8]:
    """Decode an image in full as 8-bit BGR (H x W x 3), as OpenCV orders colour: gray images
    repeated over three channels, alpha dropped, 16-bit samples scaled as :func:`to_uint8` does.
    For descriptors that take colour (learned networks); the same FrameErrors as :func:`read_gray`."""
    path = Path(path)
    return decode_colour(_file_bytes(path), path)


def decode_colour(data: NDArray[np.uint8], path: Path | str) -> NDArray[np.uint8]:
    """:func:`read_colour` of an encoded image already in memory (a ROS bag's compressed frame);
    ``path`` names the image in errors."""
    image = decode(_checked(data, path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH, path)
    if image is None or image.size == 0:
        raise FrameError(path, "cannot decode image data")
    if image.ndim != 3 or image.shape[2] != 3:
        raise FrameError(path, f"unexpected image layout {image.shape}")
    return to_uint8(check_aspect(image, path), path)


def read_gray(path: Path, min_size: tuple[int, int] | None = None) -> NDArray[np.uint8]:
    """Decode an image as 8-bit grayscale (H x W).

    With ``min_size=(w, h)`` a JPEG is decoded at the largest libjpeg reduction (1/2, 1/4, 1/8)
    that keeps both sides >= min_size, which is several times faster and, for the descriptors'
    chosen sizes, changes their values negligibly. Images already smaller than ``min_size`` are
    decoded in full (the descriptors resize them up). Raises ``FrameError`` for empty, truncated
    or undecodable files.
    """
    path = Path(path)
    return decode_gray(_file_bytes(path), path, min_size)


def decode_gray(data: NDArray[np.uint8], path: Path | str,
                min_size: tuple[int, int] | None = None) -> NDArray[np.uint8]:
    """:func:`read_gray` of an encoded image already in memory (a ROS bag's compressed frame):
    the same decode, so a JPEG gives the same pixels from a file or from a bag; ``path`` names
    the image in errors."""
    data = _checked(data, path)
    is_jpeg = data.size >= 2 and data[0] == 0xFF and data[1] == 0xD8
    factor = 1
    if is_jpeg and min_size is not None:
        full = jpeg_size(data)
        if full is None:
            raise FrameError(path, "corrupt JPEG (no frame header)")
        if full[0] * full[1] > _max_pixels():  # the reduced decode would pass OpenCV's own check
            raise _over_limit(path)
        factor = _reduction(full, min_size)
    if factor > 1:
        image = decode(data, dict(_REDUCED_FLAGS)[factor], path)
        if image is not None and (image.shape[1] < min_size[0] or image.shape[0] < min_size[1]):
            image = None  # EXIF rotation swapped the sides: decode in full instead
    else:
        image = None
    if image is None:
        image = decode(data, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH, path)
    if image is None or image.size == 0:
        raise FrameError(path, "cannot decode image data")
    if image.ndim != 2:
        raise FrameError(path, f"unexpected image layout {image.shape}")
    return to_uint8(check_aspect(image, path), path)
