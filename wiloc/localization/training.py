"""The labelled traversal pair of the ``trained`` comparator: its difference rows and truth."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from wiloc.candidates import check_exclude_recent
from wiloc.description.differences import candidate_rows, differences
from wiloc.description.traversals import Describer
from wiloc.errors import ParameterError, WilocError
from wiloc.evaluation.truth_source import TruthSource
from wiloc.methods.base import TrainingRows


@dataclass(frozen=True)
class Training:
    """A labelled traversal pair for the ``trained`` comparator (never the tested pair)."""

    query: Path
    reference: Path
    truth: TruthSource

    def state(self) -> dict[str, Any]:
        """The pair as a saved localizer's state keeps it (its traversals resolved, as the map's
        path is, and its truth's fields), so that a loaded one's results header records it."""
        return {"query": str(Path(self.query).resolve()), "reference": str(Path(self.reference).resolve()),
                "truth": asdict(self.truth)}

    @classmethod
    def restored(cls, state: Mapping[str, Any]) -> Training:
        """The pair :meth:`state` kept."""
        return cls(Path(state["query"]), Path(state["reference"]), TruthSource(**state["truth"]))


def training_rows(training: Training, describer: Describer, exclude_recent: int) -> TrainingRows:
    """The pair's truth matrix and its difference rows (query against reference), computed one
    block at a time as they are consumed (once): never all in memory."""
    R = check_exclude_recent(exclude_recent)
    tq, tr = describer.entry(Path(training.query)), describer.entry(Path(training.reference))
    try:
        truth = training.truth.load(tq.names, tr.names, str(training.query), False, R, str(training.reference))
    except WilocError as exc:  # a parameter named as the training pair's: train_radius, train_ref_path
        if exc.parameter is None:
            raise
        renamed = f"train_{exc.parameter}"
        raise (ParameterError(renamed, exc.problem) if isinstance(exc, ParameterError)
               else WilocError(None, exc.problem, parameter=renamed)) from None
    return TrainingRows(rows=candidate_rows(differences(tq, tr, describer.runner), False, R), labels=truth.matrix)
