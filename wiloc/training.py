"""The labelled traversal pair of the ``trained`` comparator: its difference rows and truth."""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wiloc.candidates import check_exclude_recent
from wiloc.differences import candidate_rows, difference_matrix
from wiloc.groundtruth import TruthSource
from wiloc.methods.base import TrainingRows
from wiloc.traversals import Describer, stage


@dataclass(frozen=True)
class Training:
    """A labelled traversal pair for the ``trained`` comparator (never the tested pair)."""

    query: Path
    reference: Path
    truth: TruthSource


def training_rows(training: Training, describer: Describer, exclude_recent: int) -> TrainingRows:
    """The pair's truth matrix and its difference rows (query against reference), read from the
    cache one block at a time as they are consumed (once): never all in memory."""
    R = check_exclude_recent(exclude_recent)
    tq, tr = describer.entry(Path(training.query)), describer.entry(Path(training.reference))
    truth = training.truth.load(tq.names, tr.names, str(training.query), False, R)
    difference_matrix(tq, tr, describer.cache, progress=stage(describer.progress, "training differences")).close()

    def rows() -> Iterator[np.ndarray]:
        with difference_matrix(tq, tr, describer.cache) as matrix:
            yield from candidate_rows(matrix, False, R)
    return TrainingRows(rows=rows(), labels=truth.matrix)
