"""Local features of one grayscale image: SIFT (float) or ORB (binary), capped per image.

The image is first brought to a common scale: shrunk (area interpolation) so its longer side is
at most ``max_side`` pixels, never enlarged, so cameras of different resolution (Gardens Point's
960 x 540 day and 640 x 360 night walks) give features at comparable scales. Then at most
``max_features`` keypoints are kept, the strongest by detector response, and described.

- ``sift``: ``cv2.SIFT_create`` (OpenCV main module), 128 float32 values per feature.
- ``orb``: ``cv2.ORB_create``, 256 bits packed into 32 uint8 per feature; compared by Hamming
  distance.

docs/fabmap.md records the choice of the defaults.
"""
from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

FEATURES = ("sift", "orb")
#: The shortest side an image may have to be searched for features: ORB's image pyramid cannot
#: shrink one a pixel high or wide (OpenCV's resize asserts), and neither detector finds any there.
MIN_SIDE = 2
#: Values per feature and their type, per feature kind.
WIDTHS = {"sift": 128, "orb": 32}
DTYPES: dict[str, np.dtype] = {"sift": np.dtype(np.float32), "orb": np.dtype(np.uint8)}


def decode_size(max_side: int) -> tuple[int, int]:
    """The smallest (w, h) a reduced JPEG decode may give without losing detail at
    ``max_side``: both sides at least ``max_side``, so the longer one certainly is."""
    return max_side, max_side


def to_scale(gray: NDArray[np.uint8], max_side: int) -> NDArray[np.uint8]:
    """The image shrunk (INTER_AREA) so that its longer side is at most ``max_side``."""
    h, w = gray.shape
    factor = max_side / max(h, w)
    if factor >= 1.0:
        return gray
    size = (max(1, round(w * factor)), max(1, round(h * factor)))
    return cv2.resize(gray, size, interpolation=cv2.INTER_AREA)


@lru_cache(maxsize=4)
def _detector(feature: str, max_features: int) -> cv2.Feature2D:
    """One detector per process and setting (their construction costs more than a small image)."""
    if feature == "sift":
        return cv2.SIFT_create(nfeatures=max_features)
    return cv2.ORB_create(nfeatures=max_features)


def extract_features(
    gray: NDArray[np.uint8], feature: str = "sift", max_features: int = 500, max_side: int = 640
) -> NDArray:
    """The local feature descriptors of one 8-bit grayscale image, ``(n, WIDTHS[feature])`` of
    ``DTYPES[feature]`` with ``n <= max_features`` (0 rows for a featureless image, and for one
    whose shorter side, once shrunk, is under ``MIN_SIDE`` pixels)."""
    if feature not in FEATURES:
        raise ValueError(f"feature must be one of {', '.join(FEATURES)}; got {feature!r}")
    image = to_scale(np.ascontiguousarray(gray, dtype=np.uint8), max_side)
    if min(image.shape) < MIN_SIDE:
        return np.zeros((0, WIDTHS[feature]), DTYPES[feature])
    keypoints, descriptors = _detector(feature, max_features).detectAndCompute(image, None)
    if descriptors is None or not keypoints:
        return np.zeros((0, WIDTHS[feature]), DTYPES[feature])
    # SIFT may return a few more than asked (one keypoint per dominant orientation): the cap is
    # enforced here, strongest first, ties kept in detection order.
    order = np.argsort([-k.response for k in keypoints], kind="stable")[:max_features]
    return np.ascontiguousarray(descriptors[np.sort(order)], dtype=DTYPES[feature])
