"""The ``bow`` descriptor: which words of a visual vocabulary an image shows (FAB-MAP's input).

Local features (SIFT or ORB, as the vocabulary was trained), each assigned to its nearest word;
the descriptor is the K-bit word-presence vector, packed 8 words per byte (uint8, the last byte
zero-padded), compared by Hamming distance like any packed-bit descriptor. Its parameters are the
vocabulary's key (what it is) and its file (where it is), so cache entries of different
vocabularies never mix. A worker process reads the vocabulary once and keeps it. The vocabulary
module (h5py, OpenCV) is imported where it is used: the command line reads the declarations.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from wiloc.descriptors.base import Descriptor, DescriptorSpec, check_names
from wiloc.errors import ParameterError, WilocError
from wiloc.parameters import Parameters, declared, param

if TYPE_CHECKING:
    from wiloc.bow.vocabulary import Vocabulary


@lru_cache(maxsize=2)
def load_vocabulary(file: str, key: str) -> Vocabulary:
    """The vocabulary in `file`, read once per process; WilocError unless its key is `key`."""
    from wiloc.bow.vocabulary import read_vocabulary

    vocabulary = read_vocabulary(Path(file))
    if vocabulary.key != key:
        raise WilocError(file, f"holds vocabulary {vocabulary.key}, expected {key}")
    return vocabulary


def compute_bow(gray: NDArray[np.uint8], vocabulary: str, file: str) -> NDArray[np.uint8]:
    """Packed word presence ``(ceil(K / 8),)`` of a grayscale image over the vocabulary `vocabulary`
    (its key) stored in `file`."""
    from wiloc.bow.vocabulary import pack_words

    return pack_words(load_vocabulary(file, vocabulary).bag_of_words(gray))


@dataclass(frozen=True)
class BowParams(Parameters):
    """The ``bow`` descriptor's parameters."""

    owner = "bow"
    file: str = param(None, "The vocabulary, an .h5 file from `wiloc vocabulary`.")
    vocabulary: str | None = param(None, "The vocabulary's key; default: read from its file (given, it must match).")


class Bow(Descriptor):
    """Visual word presence compared by the Hamming distance; what FAB-MAP reads as evidence."""

    name = "bow"
    Params = BowParams
    metric = "hamming"
    depends = "its vocabulary"
    words = True
    derived = ("vocabulary",)

    @classmethod
    def make(cls, given: Mapping[str, Any]) -> DescriptorSpec:
        """``file`` required; ``vocabulary``, its key, is read from the file (given, it must match)."""
        from wiloc.bow.features import decode_size
        from wiloc.bow.vocabulary import read_vocabulary_header

        check_names(cls.name, given, [d.name for d in declared(cls.Params)])
        if not isinstance(given.get("file"), (str, Path)):
            named = given.get("vocabulary")  # the key, read from the file: a file given there is misplaced
            hint = f"; vocabulary= is the key read from that file, got {named!r}" if named is not None else ""
            raise ValueError(f"bow needs file=<vocabulary .h5 file> (of a key in the cache: "
                             f"wiloc.api.vocabulary_file(KEY)); got {given.get('file')!r}{hint}")
        file = Path(given["file"]).expanduser().resolve()
        if not file.exists() and str(given["file"]).isalnum():  # a vocabulary's key, as --vocabulary takes
            raise ParameterError("file", f"{given['file']!r} is no vocabulary file; the file of a vocabulary key in "
                                         f"the cache is wiloc.api.vocabulary_file({str(given['file'])!r})")
        key, vocabulary, n_words = read_vocabulary_header(file)
        if given.get("vocabulary") not in (None, key):
            raise ValueError(f"bow vocabulary {given['vocabulary']!r} does not match {file} (key {key})")
        params = cls.Params(file=str(file), vocabulary=key).as_dict()
        return cls._spec(params, dtype=np.dtype(np.uint8), length=(n_words + 7) // 8, scale=1.0,
                         min_size=decode_size(vocabulary.max_side), natural_max=float(n_words))

    @classmethod
    def compute(cls, image: NDArray[np.uint8], params: Mapping[str, Any]) -> NDArray:
        return compute_bow(image, **params)

    @classmethod
    def feature_setting(cls, params: Mapping[str, Any]) -> dict[str, Any]:
        """The vocabulary's feature setting: the cache keeps an image's features by it, shared
        with the vocabulary's training and with every vocabulary of the same setting."""
        return load_vocabulary(params["file"], params["vocabulary"]).params.feature_setting()

    @classmethod
    def from_features(cls, features: NDArray, params: Mapping[str, Any]) -> NDArray:
        from wiloc.bow.vocabulary import pack_words

        return pack_words(load_vocabulary(params["file"], params["vocabulary"]).occurrences(features))

    @classmethod
    def doubts(cls, params: Mapping[str, Any]) -> list[str]:
        """A vocabulary of too few words per image makes every result doubtful."""
        sparse = load_vocabulary(params["file"], params["vocabulary"]).too_few_words()
        return [] if sparse is None else [sparse]

    @classmethod
    def traversal_doubts(cls, data: NDArray, params: Mapping[str, Any]) -> list[str]:
        """Images that give too few words by the vocabulary's own rule
        (``wiloc.bow.vocabulary.word_shortage``): what is localised on them degenerates. Said only of
        a vocabulary that passes that rule itself: a sparse one is warned of already (:meth:`doubts`),
        and its images' few words may be its own doing (a vocabulary of 16 words)."""
        from wiloc.bow.vocabulary import word_shortage

        if load_vocabulary(params["file"], params["vocabulary"]).too_few_words() is not None:
            return []
        shortage = word_shortage(np.unpackbits(np.asarray(data, dtype=np.uint8), axis=1).sum(axis=1))
        return [] if shortage is None else [
            f"its {len(data)} images {shortage}: too few local features (images too small, dark or blurred), "
            "so their bag-of-words matching and FAB-MAP's evidence degenerate"]
