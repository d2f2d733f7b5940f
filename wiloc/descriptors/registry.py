"""Descriptor registry: name -> ``DescriptorSpec`` (how to compute, store and compare it).

A spec holds only data (name, parameters, storage facts); ``compute`` looks the kernel up by
name, so a spec pickles cheaply into worker processes. ``params`` always holds every parameter
(defaults filled in), so equal descriptors give equal cache keys.
"""
from __future__ import annotations

import json
from pathlib import Path
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.descriptors import bow, brisk_gist, gist, sad
from wiloc.features import decode_size
from wiloc.vocabulary import read_vocabulary_header

DESCRIPTOR_NAMES = ("sad", "gist", "brisk-gist")
METRICS = ("l1", "sqeuclidean", "hamming", "cosine")

# Smallest decode (w, h) per descriptor that keeps its result: the resize target times a factor
# measured on Gardens Point (docs/descriptors.md, "Reduced decode").
SAD_DECODE_FACTOR = 6
GIST_DECODE_FACTOR = 1
BRISK_DECODE_FACTOR = 1

_COMPUTE: dict[str, Callable[..., NDArray]] = {
    "sad": sad.compute_sad,
    "gist": gist.compute_gist,
    "brisk-gist": brisk_gist.compute_brisk_gist,
    "bow": bow.compute_bow,
}


@dataclass(frozen=True)
class DescriptorSpec:
    """Everything the pipeline needs to know about one descriptor with fixed parameters."""

    name: str
    params: Mapping[str, Any]
    metric: str
    dtype: np.dtype
    length: int
    scale: float
    min_size: tuple[int, int] | None
    natural_max: float | None

    @property
    def key(self) -> str:
        """Canonical JSON of name and parameters: the descriptor part of a cache key."""
        return json.dumps({"name": self.name, "params": dict(self.params)}, sort_keys=True)

    def compute(self, gray: NDArray[np.uint8]) -> NDArray:
        """Descriptor of one 8-bit grayscale image, flat, ``(length,)`` of ``dtype``."""
        if self.name not in _COMPUTE:
            raise TypeError(f"'{self.name}' descriptors are imported, not computed")
        return _COMPUTE[self.name](gray, **self.params)


def _choose(value: Any, choices: tuple, what: str) -> Any:
    if value not in choices:
        raise ValueError(f"{what} must be one of {', '.join(map(repr, choices))}; got {value!r}")
    return value


def _check_params(
    name: str, given: Mapping[str, Any], defaults: Mapping[str, Any]
) -> dict[str, Any]:
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        valid = ", ".join(defaults) or "none"
        raise ValueError(f"unknown parameter(s) {', '.join(unknown)} for '{name}'; valid: {valid}")
    return {**defaults, **given}


def _sad(params: Mapping[str, Any]) -> DescriptorSpec:
    p = _check_params("sad", params, {"crop": "none", "patch": 8, "storage": "uint8"})
    _choose(p["crop"], sad.CROPS, "sad crop")
    _choose(p["patch"], sad.PATCHES, "sad patch")
    _choose(p["storage"], sad.STORAGES, "sad storage")
    rows = 2 if p["crop"] == "top-half" else 1
    f = SAD_DECODE_FACTOR
    return DescriptorSpec(
        name="sad",
        params=p,
        metric="l1",
        dtype=np.dtype(np.float32 if p["storage"] == "float32" else np.uint8),
        length=sad.LENGTH,
        scale=sad.scale(p["storage"]),
        min_size=(sad.WIDTH * f, sad.HEIGHT * rows * f),
        natural_max=sad.natural_max(p["storage"]),
    )


def _gist(params: Mapping[str, Any]) -> DescriptorSpec:
    p = _check_params("gist", params, {})
    side = gist.IMAGE_SIZE * GIST_DECODE_FACTOR
    return DescriptorSpec(
        name="gist",
        params=p,
        metric="sqeuclidean",
        dtype=np.dtype(np.float32),
        length=gist.LENGTH,
        scale=1.0,
        min_size=(side, side),
        natural_max=None,
    )


def _brisk_gist(params: Mapping[str, Any]) -> DescriptorSpec:
    p = _check_params("brisk-gist", params, {"keypoint_size": 48.0})
    size = p["keypoint_size"]
    if isinstance(size, bool) or not isinstance(size, (int, float)) or not 4 <= size <= 96:
        raise ValueError(f"brisk-gist keypoint_size must be a number in [4, 96]; got {size!r}")
    p["keypoint_size"] = float(size)
    side = brisk_gist.IMAGE_SIZE * BRISK_DECODE_FACTOR
    return DescriptorSpec(
        name="brisk-gist",
        params=p,
        metric="hamming",
        dtype=np.dtype(np.uint8),
        length=brisk_gist.LENGTH,
        scale=1.0,
        min_size=(side, side),
        natural_max=float(brisk_gist.LENGTH * 8),
    )


def _bow(params: Mapping[str, Any]) -> DescriptorSpec:
    """Word presence over a vocabulary: ``file`` (a vocabulary .h5) required; ``vocabulary``, its
    key, is read from the file (given, it must match)."""
    p = _check_params("bow", params, {"file": None, "vocabulary": None})
    if not isinstance(p["file"], (str, Path)):
        raise ValueError(f"bow needs file=<vocabulary .h5 file>; got {p['file']!r}")
    file = Path(p["file"]).expanduser().resolve()
    key, vocabulary, n_words = read_vocabulary_header(file)
    if p["vocabulary"] not in (None, key):
        raise ValueError(f"bow vocabulary {p['vocabulary']!r} does not match {file} (key {key})")
    return DescriptorSpec(
        name="bow",
        params={"file": str(file), "vocabulary": key},
        metric="hamming",
        dtype=np.dtype(np.uint8),
        length=(n_words + 7) // 8,
        scale=1.0,
        min_size=decode_size(vocabulary.max_side),
        natural_max=float(n_words),
    )


def _external(params: Mapping[str, Any]) -> DescriptorSpec:
    """A user's matrix: ``metric`` and ``length`` required; ``dtype`` uint8 for hamming."""
    p = _check_params("external", params, {"metric": None, "length": None, "dtype": "float32"})
    metric = _choose(p["metric"], METRICS, "external metric")
    length = p["length"]
    if isinstance(length, bool) or not isinstance(length, int) or length < 1:
        raise ValueError(f"external length must be a positive integer; got {length!r}")
    dtype = np.dtype(p["dtype"])
    p["dtype"] = dtype.name
    if (metric == "hamming") != (dtype == np.uint8):
        raise ValueError("hamming descriptors are packed bits (uint8); other metrics need floats")
    scales = {"l1": 1.0 / length, "sqeuclidean": 1.0, "hamming": 1.0, "cosine": 1.0}
    maxima = {"l1": None, "sqeuclidean": None, "hamming": 8.0 * length, "cosine": 2.0}
    return DescriptorSpec(
        name="external",
        params=p,
        metric=metric,
        dtype=dtype,
        length=length,
        scale=scales[metric],
        min_size=None,
        natural_max=maxima[metric],
    )


_BUILDERS: dict[str, Callable[[Mapping[str, Any]], DescriptorSpec]] = {
    "sad": _sad,
    "gist": _gist,
    "brisk-gist": _brisk_gist,
    "bow": _bow,
    "external": _external,
}


def get_descriptor(name: str, **params: Any) -> DescriptorSpec:
    """The spec of a named descriptor with the given parameters (defaults for the rest).

    ``external`` describes an imported matrix: ``get_descriptor("external", metric="cosine",
    length=D, dtype="float32")``; ``bow`` a vocabulary's word presence:
    ``get_descriptor("bow", file=VOCABULARY_H5)``.
    """
    if name not in _BUILDERS:
        choices = ", ".join(DESCRIPTOR_NAMES)
        raise ValueError(f"unknown descriptor {name!r}; choose one of {choices}")
    return _BUILDERS[name](params)
