"""A visual vocabulary (FAB-MAP's codebook): K visual words clustered from training images'
local features, the bag-of-words of an image over it, and its HDF5 file.

An image's bag of words here is binary *word presence*, as FAB-MAP uses it: word q is present
when at least one of the image's local features is nearest to word q. Stored and passed around
packed, 8 words per byte (``np.packbits``, big-endian bit order, the last byte zero-padded),
like every Hamming descriptor in wiloc; ``unpack_words`` gives the boolean vector back.

Building a vocabulary from folders through the cache is ``wiloc.description.vocabulary_build``; this module
holds only what a worker process computing bags of words needs. docs/fabmap.md describes both.
"""
from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from numpy.typing import NDArray

from wiloc.bow.clustering import assign, distinct_rows, kmajority, kmeans
from wiloc.bow.features import DTYPES, WIDTHS, extract_features
from wiloc.bow.vocabulary_params import VocabularyParams
from wiloc.errors import ParameterError, WilocError
from wiloc.version import __version__

FORMAT = "wiloc-vocabulary"
FORMAT_VERSION = 1
#: Hexadecimal digits of a vocabulary's key, the name of its file in the cache (``<key>.h5``).
KEY_DIGITS = 24
#: What to do with a vocabulary file that cannot be used (in the cache: the same command builds it anew).
REBUILD = "build it again (wiloc vocabulary with its training folders and options)"
#: Images that give a median under FEW_WORDS distinct words per image, or more than a share
#: NO_WORDS of them without any, are too sparse for FAB-MAP (a vocabulary's training images, or a
#: query's or map's): Gardens Point at 640 px gives 340 (none empty), Nordland's 64 x 32
#: thumbnails 10 (5 % empty), and the bounds sit between (docs/fabmap.md).
FEW_WORDS = 50
NO_WORDS = 0.01


def pack_words(present: NDArray[np.bool_]) -> NDArray[np.uint8]:
    """Word-presence vector(s) ``(..., K)`` packed 8 words per byte ``(..., ceil(K / 8))``."""
    return np.packbits(np.asarray(present, dtype=bool), axis=-1)


def unpack_words(packed: NDArray[np.uint8], n_words: int) -> NDArray[np.bool_]:
    """Packed bag(s) of words back to boolean presence ``(..., n_words)``."""
    return np.unpackbits(np.asarray(packed, dtype=np.uint8), axis=-1, count=n_words).astype(bool)


@dataclass(frozen=True)
class Vocabulary:
    """K visual words and the word presence of the images they were trained on.

    ``centres`` is ``(K, 128)`` float32 for SIFT, ``(K, 32)`` uint8 (packed bits) for ORB.
    ``training_frames`` names the training images (resolved paths) in the order of the rows of
    ``training_occurrences`` ``(N, K)`` bool, which FAB-MAP's Chow-Liu tree and new-place
    sampling are learned from.
    """

    key: str
    params: VocabularyParams
    centres: NDArray
    training_frames: tuple[str, ...]
    training_occurrences: NDArray[np.bool_]

    @property
    def n_words(self) -> int:
        return int(self.centres.shape[0])

    def occurrences(self, features: NDArray) -> NDArray[np.bool_]:
        """Word presence ``(K,)`` of one image's local features (rows as `extract_features`)."""
        return word_presence(features, self.centres)

    def bag_of_words(self, gray: NDArray[np.uint8]) -> NDArray[np.bool_]:
        """Word presence ``(K,)`` of one 8-bit grayscale image."""
        return self.occurrences(extract_features(gray, **self.params.feature_setting()))

    def too_few_words(self) -> str | None:
        """Why this vocabulary's training images are too small for local features
        (:func:`word_shortage`), or None. FAB-MAP's tree and new-place samples come from these
        images, so everything localised with such a vocabulary degenerates (docs/fabmap.md)."""
        shortage = word_shortage(self.training_occurrences.sum(axis=1))
        if shortage is None:
            return None
        return (f"vocabulary {self.key}: its {len(self.training_frames)} training images {shortage}: "
                f"{self._sparse_cause()}, so FAB-MAP's evidence and bag-of-words matching degenerate")

    def _sparse_cause(self) -> str:
        """What keeps the training images' words few: options under ``FEW_WORDS`` (fewer words,
        or fewer features an image, than a usable image gives words), else the images themselves."""
        capped = [f"--{name.replace('_', '-')} {value}" for name, value in
                  (("words", self.params.words), ("max_features", self.params.max_features)) if value < FEW_WORDS]
        if not capped:
            return "images too small for local features"
        return f"{' and '.join(capped)} cap{'s' if len(capped) == 1 else ''} an image's words under {FEW_WORDS}"


def word_shortage(words: NDArray[np.integer]) -> str | None:
    """What makes images with these numbers of distinct words too sparse for FAB-MAP (a median
    under ``FEW_WORDS`` words per image, or more than a share ``NO_WORDS`` of them without any),
    said as "give a median of ...", or None when they are not (or there are none)."""
    words = np.asarray(words)
    if words.size == 0:
        return None
    median, empty = float(np.median(words)), int(np.count_nonzero(words == 0))
    if median >= FEW_WORDS and empty <= NO_WORDS * words.size:
        return None
    return (f"give a median of {median:g} words each and {empty} give none (usable: {FEW_WORDS} or more, "
            f"at most {NO_WORDS:.0%} without any)")


def word_presence(features: NDArray, centres: NDArray) -> NDArray[np.bool_]:
    """``(K,)`` bool: which of the ``K`` words (``centres``) is nearest to at least one feature."""
    present = np.zeros(len(centres), dtype=bool)
    if len(features):
        present[assign(features, centres)] = True
    return present


def train_vocabulary(key: str, params: VocabularyParams, frames: Sequence[str],
                     features: Sequence[NDArray], step: Callable[[int], None] | None = None) -> Vocabulary:
    """Cluster the local features of the training images (``features[i]`` of ``frames[i]``)
    into ``params.words`` words, then compute every training image's word presence.
    ``step(i)`` is called after clustering round i."""
    if len(features) != len(frames) or not frames:
        raise ValueError(f"need one feature array per training frame, at least one; got "
                         f"{len(features)} for {len(frames)} frames")
    pooled = np.concatenate(features).astype(DTYPES[params.feature])
    distinct = len(distinct_rows(pooled)) if len(pooled) else 0
    if distinct < params.words:
        repeated = f" ({distinct} distinct)" if distinct < len(pooled) else ""
        raise ParameterError("words", f"{params.words} words need at least as many distinct training features; "
                                      f"the training images gave {len(pooled)}{repeated}")
    cluster = kmeans if params.feature == "sift" else kmajority
    centres = cluster(pooled, params.words, params.iterations, params.seed, step)
    occurrences = np.array([word_presence(f, centres) for f in features], dtype=bool)
    return Vocabulary(key, params, centres, tuple(frames), occurrences)


def _digest(centres: NDArray, frames: Sequence[str], words: NDArray[np.uint8]) -> str:
    """SHA-256 of a vocabulary's arrays as stored: a file damaged since it was written is told."""
    digest = hashlib.sha256(np.ascontiguousarray(centres).tobytes())
    digest.update("\0".join(frames).encode())
    digest.update(np.ascontiguousarray(words).tobytes())
    return digest.hexdigest()


def _header_digest(key: str, params: str, n_words: int) -> str:
    """SHA-256 of what a vocabulary file's header says and its arrays' digest does not cover: its
    key, its parameters (which describe every frame's local features) and its number of words."""
    return hashlib.sha256(f"{key}\0{params}\0{n_words}".encode()).hexdigest()


def write_vocabulary(f: h5py.File, vocabulary: Vocabulary, attrs: dict[str, object]) -> None:
    """Write `vocabulary` into an open HDF5 file, with extra attributes (provenance), the digest of
    its arrays and that of its header."""
    words = pack_words(vocabulary.training_occurrences)
    params = vocabulary.params.to_json()
    f.attrs.update({
        "format": FORMAT, "format_version": FORMAT_VERSION, "wiloc_version": __version__,
        "key": vocabulary.key, "params": params,
        "n_words": vocabulary.n_words, **attrs,
        "digest": _digest(vocabulary.centres, vocabulary.training_frames, words),
        "header_digest": _header_digest(vocabulary.key, params, vocabulary.n_words),
    })
    f.create_dataset("centres", data=vocabulary.centres)
    f.create_dataset("training/frames", data=list(vocabulary.training_frames), dtype=h5py.string_dtype())
    f.create_dataset("training/words", data=words)
    # Written last: a file without it is not a finished vocabulary.
    f.attrs["complete"] = True


def _open(path: Path) -> h5py.File:
    """The vocabulary file at ``path``, open; one named as a key (the cache's ``<key>.h5``) must
    hold that key."""
    try:
        f = h5py.File(path, "r")
    except FileNotFoundError:
        raise WilocError(path, "no such vocabulary file") from None
    except OSError as exc:
        raise WilocError(path, f"unreadable vocabulary file ({exc}); {REBUILD}") from exc
    if f.attrs.get("format") != FORMAT or not f.attrs.get("complete", False):
        f.close()
        raise WilocError(path, "not a complete wiloc vocabulary file")
    key = f.attrs.get("key")
    if re.fullmatch(f"[0-9a-f]{{{KEY_DIGITS}}}", path.stem) and key != path.stem:  # a cache file copied over another
        f.close()
        raise WilocError(path, f"damaged vocabulary file: it holds vocabulary {key}, not {path.stem} as its name says; "
                               f"{REBUILD}")
    written = f.attrs.get("header_digest")  # none in a file of an older wiloc
    if written is not None and written != _header_digest(str(key), str(f.attrs.get("params")),
                                                         int(f.attrs.get("n_words", -1))):
        f.close()  # a flipped byte in its parameters described every frame's features otherwise, silently
        raise WilocError(path, f"damaged vocabulary file: its header fails its checksum; {REBUILD}")
    return f


def read_vocabulary_header(path: Path) -> tuple[str, VocabularyParams, int]:
    """(key, params, number of words) of a vocabulary file, without reading its arrays."""
    with _open(Path(path)) as f:
        return str(f.attrs["key"]), VocabularyParams(**json.loads(f.attrs["params"])), int(f.attrs["n_words"])


def read_vocabulary(path: Path) -> Vocabulary:
    """The vocabulary stored in an HDF5 file written by `write_vocabulary`."""
    path = Path(path)
    with _open(path) as f:
        try:
            params = VocabularyParams(**json.loads(f.attrs["params"]))
            n_words = int(f.attrs["n_words"])
            centres, words = f["centres"][()], f["training/words"][()]
            frames = tuple(s.decode() for s in f["training/frames"][()])
            if f.attrs.get("digest") != _digest(centres, frames, words):
                raise WilocError(path, "damaged vocabulary file: its arrays fail their checksum (or an older "
                                       f"wiloc wrote it without one); {REBUILD}")
            vocabulary = Vocabulary(
                key=str(f.attrs["key"]), params=params, centres=np.asarray(centres, dtype=DTYPES[params.feature]),
                training_frames=frames, training_occurrences=unpack_words(words, n_words))
        except (KeyError, ValueError, TypeError, OSError) as exc:
            raise WilocError(path, f"unreadable vocabulary file ({exc}); {REBUILD}") from exc
    # a NaN centre is every feature's nearest word (argmin takes NaN first): every image would
    # hold that one word alone
    centres, width = vocabulary.centres, WIDTHS[params.feature]
    if centres.shape != (n_words, width) or not np.isfinite(centres).all():
        raise WilocError(path, f"damaged vocabulary file: its centres are not {n_words} rows of {width} finite values")
    return vocabulary
