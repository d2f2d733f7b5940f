"""FAB-MAP as an observation model: each query frame's row of evidence over the map's places.

For a frame's word presence Z the row holds, per candidate place j, the log-likelihood ratio
r_j = log p(Z | L_j) - log p(Z | new place): how much better place j explains the frame than an
unseen place does (the denominator is FAB-MAP's new-place likelihood, from sampled training
images). Methods that take such rows (``rows`` holding ``"log_ratio"``: the single-frame
``fabmap`` method, and CAT-Graph, which ranks -r_j within the row as it ranks differences: the
local-feature CAT-Graph of the paper's Table I) read them as they read difference rows, with
-inf where a frame is no candidate. The Chow-Liu tree and the new-place samples are learned from
the vocabulary's training images, a traversal other than the tested pair.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from wiloc.bow.fabmap.chow_liu import ChowLiuTree
from wiloc.bow.fabmap.model import FabMap
from wiloc.bow.fabmap.params import FabMapParams
from wiloc.bow.vocabulary import Vocabulary, unpack_words
from wiloc.descriptors.bow import load_vocabulary
from wiloc.descriptors.registry import DescriptorSpec
from wiloc.parameters import Parameters


class FabMapEvidence:
    """FAB-MAP 1.0 over one vocabulary: places added from packed word-presence rows (the ``bow``
    descriptor), evidence rows for query frames."""

    def __init__(self, vocabulary: Vocabulary, params: FabMapParams | None = None) -> None:
        self.vocabulary = vocabulary
        occurrences = vocabulary.training_occurrences
        self.model = FabMap(ChowLiuTree.fit(occurrences), params, training=occurrences)

    @classmethod
    def of(cls, spec: DescriptorSpec, params: Parameters | None = None) -> FabMapEvidence:
        """The model of a ``bow`` descriptor's vocabulary, with a method's parameters when they
        are FAB-MAP's (the ``fabmap`` method's), else FAB-MAP's defaults."""
        return cls(load_vocabulary(spec.params["file"], spec.params["vocabulary"]),
                   params if isinstance(params, FabMapParams) else None)

    @property
    def training_folders(self) -> list[str]:
        """The folders of the images the vocabulary, the tree and the new-place samples come from."""
        return sorted({str(Path(frame).parent) for frame in self.vocabulary.training_frames})

    def words(self, packed: NDArray[np.uint8]) -> NDArray[np.bool_]:
        """Word presence ``(..., K)`` of packed ``bow`` rows."""
        return unpack_words(np.asarray(packed, dtype=np.uint8), self.vocabulary.n_words)

    def add_places(self, packed: NDArray[np.uint8]) -> None:
        """One map place per packed row, in order (each seen once)."""
        for z in np.atleast_2d(self.words(packed)):
            self.model.add_place(z)

    def row(self, packed: NDArray[np.uint8]) -> NDArray[np.float64]:
        """r_j = log p(Z | L_j) - log p(Z | new place) over the places so far."""
        rows, new = self.model.frame_log_likelihoods(self.words(packed))
        return rows - new

