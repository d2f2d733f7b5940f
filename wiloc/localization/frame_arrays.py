"""What a ``Localizer`` is given: a frame as an array (a camera's image, a nested list as JSON
gives, a descriptor row), checked, with what was given said when it is no frame, and an image
made the 8-bit gray or BGR image that descriptors are computed from; a frame as an image file's
path, read into one (bytes no path can be, a camera's raw pixels, said to be so); and the
traversal the frames came from, which its results record."""
from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from wiloc.atomic import name_problem
from wiloc.description.describing import is_stream
from wiloc.description.traversals import MATRIX_SUFFIXES
from wiloc.errors import FrameError, WilocError
from wiloc.sources.frames import (
    check_aspect,
    list_traversal,
    not_a_traversal,
    read_colour,
    read_gray,
    to_uint8,
    unusable_reason,
)


def frame_array(frame: object) -> NDArray:
    """A frame that is no file as an array (an image or a descriptor row; a nested list or tuple
    of numbers too, as numpy makes one of it); None, a scalar or what numpy cannot make one array
    of numbers (a ragged list, a dict) is a WilocError saying what was given and what is taken."""
    takes = "give an image file's path, an image array or a descriptor row"
    if frame is None:
        raise WilocError("observe", f"frame is None; {takes}")
    try:
        array = np.asarray(frame)
    except (TypeError, ValueError):  # rows of different lengths
        array = None
    if array is None or array.ndim == 0 or array.dtype.kind in "OUS":  # objects, text
        raise WilocError("observe", f"frame is of type {type(frame).__name__}, not an array of numbers; {takes}")
    return array


def frame_path(frame: object) -> Path | None:
    """``frame`` as a file's path when it is one (text, bytes as ``os.fsencode`` gives for a
    path that is not UTF-8, or a path object), else None. A FrameError when no file can be named
    so: an empty path (``Path("")`` would be the current folder), one holding NUL, and bytes that
    no path can be (a NUL byte, a name too long): a frame's pixels (a ROS Image's ``data``) or an
    encoded image's bytes (a ROS CompressedImage's), said to be so."""
    if not isinstance(frame, (str, bytes, os.PathLike)):
        return None
    text = os.fsdecode(frame)
    if not text:
        raise FrameError("observe", "the frame's path is empty")
    if isinstance(frame, bytes) and not os.path.lexists(frame):  # False for a NUL byte or a name too long
        if frame.startswith((b"\xff\xd8", b"\x89PNG")):
            raise FrameError("observe", "frame is the bytes of an encoded image, not a file's path: give its file, "
                                        "or the image decoded (cv2.imdecode)")
        problem = "they hold a NUL byte" if "\0" in text else name_problem(Path(text))
        what = (f"no file's path can be ({problem}):" if problem
                else f"name no file ({_shown(frame)}): a missing file, or")
        raise FrameError("observe", f"frame is {len(frame)} bytes that {what} image data, such as a ROS Image's "
                                    "data? give the image as an array "
                                    "(numpy.frombuffer(data, numpy.uint8).reshape(height, width, channels))")
    if "\0" in text:  # no file's name holds one; the system would refuse it as a ValueError
        raise FrameError("observe", "the frame's path holds a NUL character; no file is named so")
    if not Path(text).name:  # ".", "/": a folder, which a name is not taken from
        raise FrameError(text, "not a regular file")
    return Path(text)


def _shown(data: bytes, most: int = 40) -> str:
    """The first ``most`` of ``data`` as Python writes bytes (control characters escaped: one line)."""
    return repr(data[:most]) + ("..." if len(data) > most else "")


def file_image(path: Path, colour: bool, min_size: tuple[int, int] | None) -> NDArray[np.uint8]:
    """The 8-bit image of an image file, BGR for a ``colour`` descriptor, else gray (a JPEG
    decoded at the reduced size ``min_size`` allows); a file that cannot be a frame
    (``unusable_reason``: a name that is not UTF-8, a FIFO) is a FrameError saying why."""
    try:
        reason = unusable_reason(path)
        unusable = reason is not None and (path.exists() or path.is_symlink())  # a broken link or loop: said so
    except OSError as exc:  # a name too long for the file system
        raise FrameError(path, f"cannot read file ({exc.strerror or exc})") from None
    if unusable:
        raise FrameError(path, reason)
    return read_colour(path) if colour else read_gray(path, min_size)


def check_query(query: Path, described: bool) -> None:
    """Refuse, as a batch run refuses its query, a traversal recorded as a streaming run's query
    that is none: missing (``folder does not exist``, as listing says), neither a folder nor a
    regular file (a FIFO, a device), a file that is no video, ROS bag or descriptor matrix (``an
    image file is not a traversal``), or a descriptor matrix file where the frames were
    ``described`` from images. A folder is taken as it is (a ROS 2 bag's, or one a live source
    empties as its frames are read)."""
    if not query.exists():
        list_traversal(query)  # says what is missing, as a batch run does
    if not (query.is_dir() or query.is_file()):
        raise WilocError(query, "not a folder, video, ROS bag or descriptor matrix file")
    if query.is_file() and not (is_stream(query) or query.suffix.lower() in MATRIX_SUFFIXES):
        raise WilocError(query, not_a_traversal(query, "give the folder of images, video, ROS bag or descriptor "
                                                       "matrix file the frames came from"))
    if query.is_file() and not is_stream(query) and described:
        raise WilocError(query, "a descriptor matrix file, but the frames were described from images: give the "
                                "folder, video or ROS bag they came from")


def gray_image(array: NDArray) -> NDArray[np.uint8]:
    """An image array as the 8-bit gray image descriptors are computed from: gray (H x W, or
    H x W x 1) or BGR/BGRA as OpenCV decodes, of 8- or 16-bit integers (16-bit scaled by
    255/65535, as a 16-bit file is), of other integers in [0, 255] (a nested list's int64, read as
    8-bit) or of floats in [0, 1] (scaled by 255 and rounded). Anything else is a WilocError saying
    what was given."""
    array = _image_samples(array)
    if array.ndim == 3:
        array = cv2.cvtColor(array, cv2.COLOR_BGR2GRAY if array.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return to_uint8(array, "observe")


def colour_image(array: NDArray) -> NDArray[np.uint8]:
    """An image array as the 8-bit BGR image colour descriptors (``onnx``) are computed from:
    the arrays :func:`gray_image` takes, gray repeated over three channels, alpha dropped."""
    array = _image_samples(array)
    if array.ndim == 2:
        array = cv2.cvtColor(array, cv2.COLOR_GRAY2BGR)
    elif array.shape[2] == 4:
        array = cv2.cvtColor(array, cv2.COLOR_BGRA2BGR)
    return to_uint8(array, "observe")


def _image_samples(array: NDArray) -> NDArray:
    """An image array checked (gray, BGR or BGRA; not empty; 8- or 16-bit integers, other integers
    in [0, 255] or floats in [0, 1], both of which become 8-bit), a single channel's last axis
    dropped. Integers of another type are read as 8-bit values, as a nested list of Python ints
    (JSON's) spells an 8-bit image: one outside [0, 255] is refused, never wrapped or scaled."""
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] in (3, 4))):
        raise WilocError("observe", f"an image must be gray (H x W) or BGR/BGRA (H x W x 3 or 4), got shape {array.shape}")
    if array.shape[0] == 0 or array.shape[1] == 0:
        raise WilocError("observe", f"an empty image ({array.shape[0]} x {array.shape[1]} pixels)")
    check_aspect(array, "observe")
    if array.dtype.kind == "f":
        if not np.all((array >= 0) & (array <= 1)):
            raise WilocError("observe", f"a {array.dtype} image must hold values in [0, 1] ({_float_range(array)})")
        array = np.rint(array * 255).astype(np.uint8)
    elif array.dtype.kind in "iu" and array.dtype not in (np.uint8, np.uint16):
        low, high = int(array.min()), int(array.max())
        if low < 0 or high > 255:
            raise WilocError("observe", f"an image of {array.dtype} values in [{low}, {high}]; integers other than "
                                        "uint8 and uint16 are read as 8-bit values in [0, 255]: give 16-bit values "
                                        "as a uint16 array")
        array = array.astype(np.uint8)
    elif array.dtype not in (np.uint8, np.uint16):
        raise WilocError("observe", f"an image of {array.dtype} values; give 8- or 16-bit integers or floats in [0, 1]")
    return array


def _float_range(array: NDArray[np.floating]) -> str:
    """What a float image outside [0, 1] holds: NaN, or its range, with what to do when that is
    an 8-bit image's (a ``cv2.imread(...).astype(np.float32)``, a network's input before scaling:
    values up to 255, beyond 1.5; not a scaled image's rounding, 1.0000001)."""
    if np.isnan(array).any():
        return "NaN found"
    low, high = array.min(), array.max()
    hint = ": an 8-bit image's values, give it as uint8 or divided by 255" if low >= 0 and 1.5 < high <= 255 else ""
    return f"values in [{_bound(low)}, {_bound(high)}] found{hint}"


def _bound(value: np.floating) -> str:
    """``value`` in 6 significant digits, or in as many as show it outside [0, 1] when those
    round it into [0, 1] (1.0000001, not 1)."""
    short = f"{value:g}"
    return short if (0 <= float(short) <= 1) == (0 <= value <= 1) else str(value)
