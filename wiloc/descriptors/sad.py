"""The ``sad`` descriptor: a tiny patch-normalised thumbnail (SeqSLAM / RatSLAM style).

Grayscale, optional crop, 48 x 24 (w x h) with area interpolation, then every ``patch`` x
``patch`` block shifted to zero mean and scaled to unit (population) standard deviation; a block
that is numerically flat becomes 0. Stored forms (``storage``):

- ``uint8``: ``clip(round(128 + 32 z), 0, 255)``; the raw difference is the sum of absolute
  differences of bytes (SIMD ``vpsadbw``), scale ``1 / (32 * 1152)`` gives the mean absolute
  difference in z units.
- ``float32``: z itself, scale ``1 / 1152``.
- ``seqslam``: OpenSeqSLAM's ``127 + round(z)`` bytes, scale ``1 / 1152``.

docs/descriptors.md records the recall measurements behind the default.

OpenCV is imported where it is used: the command line builds its options from this module's
declarations without loading it.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from wiloc.descriptors.base import Descriptor, DescriptorSpec
from wiloc.errors import ParameterError
from wiloc.parameters import Parameters, param

WIDTH, HEIGHT = 48, 24
LENGTH = WIDTH * HEIGHT
CROPS = ("none", "top-half")
STORAGES = ("uint8", "float32", "seqslam")
PATCHES = tuple(p for p in range(2, HEIGHT + 1) if WIDTH % p == 0 and HEIGHT % p == 0)
QUANT_OFFSET, QUANT_STEP = 128.0, 32.0
SEQSLAM_OFFSET = 127.0
_FLAT_STD = 1e-3  # gray levels; float32 resize rounding of a flat area stays far below it
#: Smallest decode (w, h) that keeps the result: the thumbnail times this factor, measured on
#: Gardens Point (docs/descriptors.md, "Reduced decode").
DECODE_FACTOR = 6


def crop_image(gray: NDArray[np.uint8], crop: str) -> NDArray[np.uint8]:
    """Apply the named crop ('none' or 'top-half': the upper half, as in the paper's run)."""
    if crop == "top-half":
        return gray[: max(gray.shape[0] // 2, 1)]
    return gray


def patch_normalise(image: NDArray[np.floating], patch: int) -> NDArray[np.float32]:
    """Every ``patch`` x ``patch`` block to zero mean and unit population std (flat block -> 0)."""
    h, w = image.shape
    blocks = image.astype(np.float64).reshape(h // patch, patch, w // patch, patch)
    mean = blocks.mean(axis=(1, 3), keepdims=True)
    std = blocks.std(axis=(1, 3), keepdims=True)
    flat = std <= _FLAT_STD
    z = np.where(flat, 0.0, (blocks - mean) / np.where(flat, 1.0, std))
    return z.reshape(h, w).astype(np.float32)


def sad_z(gray: NDArray[np.uint8], crop: str = "none", patch: int = 8) -> NDArray[np.float32]:
    """The patch-normalised 24 x 48 thumbnail (float z values) of a grayscale image."""
    import cv2

    image = crop_image(gray, crop).astype(np.float32)
    small = cv2.resize(image, (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA)
    return patch_normalise(small, patch)


def quantise(z: NDArray[np.float32], storage: str) -> NDArray:
    """Flat stored form of z values for the given storage (see module docstring)."""
    flat = z.reshape(-1)
    if storage == "float32":
        return flat.astype(np.float32)
    if storage == "seqslam":
        return np.clip(np.rint(SEQSLAM_OFFSET + flat), 0, 255).astype(np.uint8)
    return np.clip(np.rint(QUANT_OFFSET + QUANT_STEP * flat), 0, 255).astype(np.uint8)


def dequantise(stored: NDArray, storage: str) -> NDArray[np.float32]:
    """z values back from a stored form (exact up to the quantisation step and clipping)."""
    values = stored.astype(np.float32)
    if storage == "float32":
        return values
    if storage == "seqslam":
        return values - np.float32(SEQSLAM_OFFSET)
    return (values - np.float32(QUANT_OFFSET)) / np.float32(QUANT_STEP)


def compute_sad(
    gray: NDArray[np.uint8], crop: str = "none", patch: int = 8, storage: str = "uint8"
) -> NDArray:
    """The ``sad`` descriptor of a grayscale image: 1152 values in the chosen storage."""
    return quantise(sad_z(gray, crop, patch), storage)


def scale(storage: str) -> float:
    """Factor turning the raw sum of absolute differences into the mean absolute z difference."""
    step = QUANT_STEP if storage == "uint8" else 1.0
    return 1.0 / (step * LENGTH)


def natural_max(storage: str) -> float:
    """Largest possible mean absolute z difference.

    Within a block of n unit-std values sum|z| <= n, so sum|a - b| <= 2n: the mean is at most 2.
    Rounding adds at most one step per value (1/32 for uint8, 1 for seqslam); clipping only
    shrinks differences.
    """
    return {"float32": 2.0, "uint8": 2.0 + 1.0 / QUANT_STEP, "seqslam": 3.0}[storage]


@dataclass(frozen=True)
class SadParams(Parameters):
    """The ``sad`` descriptor's parameters."""

    owner = "sad"
    crop: Literal["none", "top-half"] = param(
        "none", "Crop before resizing: top-half keeps the upper half of the image (the paper's run).")
    patch: int = param(8, "Side in pixels of the blocks of the 48 x 24 thumbnail normalised to zero mean and "
                          "unit std; it must divide 24.", low=PATCHES[0], high=PATCHES[-1])
    storage: Literal["uint8", "float32", "seqslam"] = param(
        "uint8", "Stored form of the z values: 128 + 32 z in bytes (compared with SIMD), z itself, or "
                 "OpenSeqSLAM's 127 + z.")

    def check(self) -> None:
        if self.patch not in PATCHES:
            raise ParameterError("patch", f"must divide the thumbnail's sides {WIDTH} and {HEIGHT} "
                                          f"(one of {', '.join(map(str, PATCHES))}), got {self.patch!r}")


class Sad(Descriptor):
    """Patch-normalised thumbnails compared by the mean absolute difference."""

    name = "sad"
    Params = SadParams
    metric = "l1"

    @classmethod
    def spec(cls, params: dict[str, Any]) -> DescriptorSpec:
        rows = 2 if params["crop"] == "top-half" else 1
        storage = params["storage"]
        return cls._spec(params, dtype=np.dtype(np.float32 if storage == "float32" else np.uint8), length=LENGTH,
                         scale=scale(storage), min_size=(WIDTH * DECODE_FACTOR, HEIGHT * rows * DECODE_FACTOR),
                         natural_max=natural_max(storage))

    @classmethod
    def compute(cls, image: NDArray[np.uint8], params: Mapping[str, Any]) -> NDArray:
        return compute_sad(image, **params)
