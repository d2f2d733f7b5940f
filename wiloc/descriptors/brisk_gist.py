"""The ``brisk-gist`` descriptor: BRIEF-Gist with OpenCV's BRISK in place of BRIEF.

Grayscale, resized to 240 x 240 (area interpolation), cut into 5 x 5 tiles of 48 x 48; one
512-bit BRISK descriptor is computed at each tile centre and the 25 are stored row by row
(tile row, then tile column) as 1600 bytes. OpenCV's BRISK always estimates the keypoint
orientation and steers its pattern; it also drops keypoints whose pattern leaves the image, so
the image is padded (reflected) by more than the pattern reaches and the 25 keypoints that come
back are matched to their tiles by position.

OpenCV is imported where it is used: the command line builds its options from this module's
declarations without loading it.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from wiloc.descriptors.base import Descriptor, DescriptorSpec
from wiloc.parameters import Parameters, param

if TYPE_CHECKING:  # for annotations only: OpenCV loads where it is used
    import cv2

IMAGE_SIZE = 240
TILES = 5
TILE = IMAGE_SIZE // TILES
BYTES = 64
LENGTH = TILES * TILES * BYTES
# Measured: a keypoint of size s survives OpenCV's border check from about 1.6 s off the edge
# (20 px at s = 12, 76 px at s = 48, 99 px at s = 64); padding keeps every centre >= 1.7 s away.
_PAD_PER_SIZE = 1.7
#: Smallest decode (w, h) that keeps the result: the resize target times this factor
#: (docs/descriptors.md, "Reduced decode").
DECODE_FACTOR = 1


@lru_cache(maxsize=1)
def _brisk() -> cv2.BRISK:
    """One BRISK extractor per process (default thresholds; only compute() is used)."""
    import cv2

    return cv2.BRISK_create()


def compute_brisk_gist(
    gray: NDArray[np.uint8], keypoint_size: float = 48.0
) -> NDArray[np.uint8]:
    """25 tile-centre BRISK descriptors of a grayscale image, flat (1600 uint8)."""
    import cv2

    image = cv2.resize(gray, (IMAGE_SIZE, IMAGE_SIZE), interpolation=cv2.INTER_AREA)
    pad = max(0, math.ceil(_PAD_PER_SIZE * keypoint_size) - TILE // 2)
    padded = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_REFLECT_101)
    centres = [
        (pad + TILE * col + TILE / 2.0, pad + TILE * row + TILE / 2.0)
        for row in range(TILES)
        for col in range(TILES)
    ]
    keypoints = [cv2.KeyPoint(x, y, keypoint_size) for x, y in centres]
    kept, descriptors = _brisk().compute(padded, keypoints)
    if descriptors is None or len(kept) != len(centres):
        raise RuntimeError(f"BRISK kept {len(kept)} of {len(centres)} tile keypoints")
    out = np.empty((len(centres), BYTES), dtype=np.uint8)
    lookup = {(round(x), round(y)): i for i, (x, y) in enumerate(centres)}
    placed = np.zeros(len(centres), dtype=bool)
    for keypoint, descriptor in zip(kept, descriptors):
        tile = lookup.get((round(keypoint.pt[0]), round(keypoint.pt[1])))
        if tile is None or placed[tile]:
            raise RuntimeError(f"BRISK returned an unexpected keypoint at {keypoint.pt}")
        out[tile] = descriptor
        placed[tile] = True
    return out.reshape(-1)


@dataclass(frozen=True)
class BriskGistParams(Parameters):
    """The ``brisk-gist`` descriptor's parameters."""

    owner = "brisk-gist"
    keypoint_size: float = param(48.0, "BRISK keypoint size in pixels of the 240 x 240 image (a tile is 48).",
                                 low=4, high=96)


class BriskGist(Descriptor):
    """25 tile-centre BRISK descriptors compared by the Hamming distance."""

    name = "brisk-gist"
    Params = BriskGistParams
    metric = "hamming"

    @classmethod
    def spec(cls, params: dict[str, Any]) -> DescriptorSpec:
        side = IMAGE_SIZE * DECODE_FACTOR
        return cls._spec(params, dtype=np.dtype(np.uint8), length=LENGTH, scale=1.0, min_size=(side, side),
                         natural_max=float(LENGTH * 8))

    @classmethod
    def compute(cls, image: NDArray[np.uint8], params: Mapping[str, Any]) -> NDArray:
        return compute_brisk_gist(image, **params)
