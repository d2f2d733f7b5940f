"""The ``bow`` descriptor: which words of a visual vocabulary an image shows (FAB-MAP's input).

Local features (SIFT or ORB, as the vocabulary was trained), each assigned to its nearest word;
the descriptor is the K-bit word-presence vector, packed 8 words per byte (uint8, the last byte
zero-padded), compared by Hamming distance like any packed-bit descriptor. Its parameters are the
vocabulary's key (what it is) and its file (where it is), so cache entries of different
vocabularies never mix. A worker process reads the vocabulary once and keeps it.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from wiloc.errors import WilocError
from wiloc.vocabulary import Vocabulary, pack_words, read_vocabulary


@lru_cache(maxsize=2)
def load_vocabulary(file: str, key: str) -> Vocabulary:
    """The vocabulary in `file`, read once per process; WilocError unless its key is `key`."""
    vocabulary = read_vocabulary(Path(file))
    if vocabulary.key != key:
        raise WilocError(file, f"holds vocabulary {vocabulary.key}, expected {key}")
    return vocabulary


def compute_bow(gray: NDArray[np.uint8], vocabulary: str, file: str) -> NDArray[np.uint8]:
    """Packed word presence ``(ceil(K / 8),)`` of a grayscale image over the vocabulary `vocabulary`
    (its key) stored in `file`."""
    return pack_words(load_vocabulary(file, vocabulary).bag_of_words(gray))
