"""A streaming run's results: the decisions a ``Localizer`` made, kept as it goes, and the
results a batch run of the same frames gives (``wiloc.api.evaluate`` scores them, ``Results.save``
writes the file ``wiloc evaluate`` and ``wiloc compare`` read); the header a followed folder's
results file starts with."""
from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from wiloc.decisions import Decision, Decisions
from wiloc.description.traversals import descriptors_digest
from wiloc.errors import WilocError
from wiloc.evaluation.results import Results, make_results
from wiloc.evaluation.results_header import ResultsHeader
from wiloc.localization.run_files import run_header
from wiloc.localization.session import RunSession
from wiloc.localization.training import Training

#: Decisions kept as objects before they are packed into arrays (a few hundred bytes a frame).
PACKED = 1024


class DecisionLog:
    """Every decision of a streaming run, in order, in the batch form results are written from
    (``Decisions``): packed into arrays every :data:`PACKED` frames, so that a long run keeps
    about 60 bytes a frame, and 8 more per ranked candidate (20 for the methods that rank)."""

    def __init__(self, columns: tuple[str, ...], ranked: bool, kept: Decisions | None = None) -> None:
        self.columns, self.ranked = columns, ranked
        self._packed = [kept if kept is not None else Decisions.collect([], columns, ranked=ranked)]
        self._recent: list[Decision] = []

    def __len__(self) -> int:
        return sum(map(len, self._packed)) + len(self._recent)

    def append(self, decision: Decision) -> None:
        self._recent.append(decision)
        if len(self._recent) == PACKED:
            self._packed.append(Decisions.collect(self._recent, self.columns, ranked=self.ranked))
            self._recent = []

    def decisions(self, **kwargs: Any) -> Decisions:
        """Every decision so far as one ``Decisions`` (``kwargs``: its ``model`` and ``params``)."""
        recent = Decisions.collect(self._recent, self.columns, ranked=self.ranked)
        return Decisions.concatenated([*self._packed, recent], **kwargs)

    def state(self) -> dict[str, Any]:
        """The decisions as arrays, for a saved localizer's state."""
        kept = self.decisions()
        return {"match": kept.match, "difference": kept.difference, "confidence": kept.confidence,
                "stage": kept.stage, "columns": kept.columns, "ranking": kept.ranking}

    @classmethod
    def restored(cls, columns: tuple[str, ...], ranked: bool, state: Mapping[str, Any]) -> DecisionLog:
        """The log :meth:`state` saved."""
        kept = Decisions(match=state["match"], difference=state["difference"], confidence=state["confidence"],
                         stage=np.asarray(state["stage"], dtype=np.str_), columns=dict(state["columns"]),
                         ranking=state["ranking"])
        return cls(columns, ranked, kept)


def streamed_header(session: RunSession, query: str | os.PathLike | None) -> ResultsHeader:
    """What a streaming run's results header says of it: its setup and inputs (as a batch run's
    header says them: the map's digest, a video's sampling, a bag's topic, FAB-MAP's rows; no
    query digest), the method's parameters as they are now and the map's frames (none in
    sequence mode, where they are the frames observed). ``query`` is the traversal the frames
    came from, if known (None: recorded as "")."""
    training = session.training if isinstance(session.training, Training) else None
    reference = session.map_path if session.map_path is not None else session.map
    header = run_header(session.method.name, session.describer, None if query is None else Path(query),
                        session.metric, reference, session.exclude_recent, training)
    return replace(header, params=session.method.header(), **session.recorded(),
                   reference_frames=() if session.map is None else tuple(session.map.names))


def streamed_results(session: RunSession, log: DecisionLog, names: list[str], query: str | os.PathLike | None
                     ) -> Results:
    """The results of the frames ``names`` decided as ``log`` holds them: the rows, header and
    model a batch run of the same frames gives, but for the query's digest against a map (a
    streaming run keeps no query descriptors there; in sequence mode they are its candidates).
    No frame yet is a WilocError: there is nothing to score."""
    if not names:
        raise WilocError("results", "no frame observed yet: results hold the decisions of the frames observed")
    method = session.method
    header = streamed_header(session, query)
    if session.map is None:
        header = replace(header, query_digest=descriptors_digest(names, session.seen))
    decisions = log.decisions(model=method.model, params=method.header())
    return make_results(decisions, query_names=names, header=header,
                        ref_names=names if session.map is None else session.map.names)
