"""A frame given to ``Localizer.observe`` as an array (a camera's image, a nested list as JSON
gives, a descriptor row): checked, with what was given said when it is no frame, and an image
made the 8-bit gray or BGR image that descriptors are computed from; an image file read into one."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from wiloc.errors import FrameError, WilocError
from wiloc.sources.frames import (
    check_aspect,
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
    if array is None or array.ndim == 0 or array.dtype == object:
        raise WilocError("observe", f"frame is of type {type(frame).__name__}, not an array of numbers; {takes}")
    return array


def file_image(path: Path, colour: bool, min_size: tuple[int, int] | None) -> NDArray[np.uint8]:
    """The 8-bit image of an image file, BGR for a ``colour`` descriptor, else gray (a JPEG
    decoded at the reduced size ``min_size`` allows); a file that cannot be a frame
    (``unusable_reason``: a name that is not UTF-8, a FIFO) is a FrameError saying why."""
    try:
        reason = unusable_reason(path)
    except OSError as exc:  # a name too long for the file system
        raise FrameError(path, f"cannot read file ({exc.strerror or exc})") from None
    if reason is not None and path.exists():
        raise FrameError(path, reason)
    return read_colour(path) if colour else read_gray(path, min_size)


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
