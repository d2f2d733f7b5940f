"""What a method decides: one query frame's :class:`Decision` (streaming) and a batch run's
:class:`Decisions` (arrays, one row per frame), the form results files are written from."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.model import HistogramModel
from wiloc.reprs import short_repr


@dataclass(frozen=True)
class Decision:
    """One query frame's decision.

    ``match`` is the candidate's position (-1 when undecided); ``difference`` its difference;
    ``confidence`` the method's belief that the match is the same place (NaN when undecided);
    ``new_place`` the probability that the frame shows a place absent from the map (NaN where the
    method has none); ``stage`` what the method did (``init``, ``update``, ``track``, ``none``);
    ``extra`` method-specific values (``m_r`` of the online model). ``frame`` and ``match_name``
    carry frame names where the caller knows them (``Localizer``). ``ranking`` holds the
    positions of the best candidates, best first (the match first), for methods that rank
    (:attr:`Method.ranks`), when the frame has a match: the row's best, unless the method ranks
    the map its own way (CAT-Graph: by its posterior).
    """

    match: int
    difference: float
    confidence: float
    stage: str
    new_place: float = float("nan")
    extra: Mapping[str, float] = field(default_factory=dict)
    frame: str = ""
    match_name: str = ""
    ranking: tuple[int, ...] = ()

    @property
    def decided(self) -> bool:
        return self.match >= 0 and not np.isnan(self.confidence)


@short_repr
@dataclass
class Decisions:
    """Per query frame of a batch run: best match, its difference, confidence and stage.

    ``match`` is -1 and ``difference``/``confidence`` are NaN for undecided frames (for example
    the online model's initialisation stage). ``columns`` holds method-specific per-frame values
    (``m_r`` for the online model, ``new_place`` for CAT-Graph). ``ranking`` (methods that rank
    only) holds each frame's best candidates, best first, one row per frame padded with -1.
    """

    match: NDArray[np.int64]
    difference: NDArray[np.float64]
    confidence: NDArray[np.float64]
    stage: NDArray[np.str_]
    columns: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    model: HistogramModel | None = None
    params: dict[str, Any] = field(default_factory=dict)
    ranking: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        n = len(self.match)
        self.match = np.asarray(self.match, dtype=np.int64)
        self.difference = np.asarray(self.difference, dtype=np.float64)
        self.confidence = np.asarray(self.confidence, dtype=np.float64)
        self.stage = np.asarray(self.stage, dtype=np.str_)
        ranking = [] if self.ranking is None else [("ranking", self.ranking)]
        for name, arr in [("difference", self.difference), ("confidence", self.confidence),
                          ("stage", self.stage), *self.columns.items(), *ranking]:
            if len(arr) != n:
                raise ValueError(f"{name} has {len(arr)} rows, match has {n}")

    def __len__(self) -> int:
        return len(self.match)

    @property
    def decided(self) -> NDArray[np.bool_]:
        """Frames that carry a decision (a match and a confidence)."""
        return (self.match >= 0) & np.isfinite(self.confidence)

    @classmethod
    def collect(cls, steps: list[Decision], columns: tuple[str, ...], *, ranked: bool = False,
                **kwargs: Any) -> Decisions:
        """The batch form of per-frame decisions; ``columns`` names the per-frame extras kept
        (``new_place`` reads :attr:`Decision.new_place`, any other name ``Decision.extra``);
        ``ranked`` keeps the rankings."""
        def column(name: str) -> NDArray[np.float64]:
            return np.array([d.new_place if name == "new_place" else d.extra.get(name, np.nan) for d in steps],
                            dtype=np.float64)
        ranking = None
        if ranked:
            ranking = np.full((len(steps), max((len(d.ranking) for d in steps), default=0)), -1, dtype=np.int64)
            for row, d in zip(ranking, steps):
                row[:len(d.ranking)] = d.ranking
        return cls(match=np.array([d.match for d in steps], dtype=np.int64),
                   difference=np.array([d.difference for d in steps], dtype=np.float64),
                   confidence=np.array([d.confidence for d in steps], dtype=np.float64),
                   stage=np.array([d.stage for d in steps], dtype=np.str_),
                   columns={name: column(name) for name in columns}, ranking=ranking, **kwargs)

    @classmethod
    def concatenated(cls, parts: list[Decisions], **kwargs: Any) -> Decisions:
        """The decisions of consecutive ``parts`` (one at least, of one run: the same columns, all
        ranked or none) as one, their rankings padded with -1 to the widest, as :meth:`collect` pads."""
        def joined(name: str) -> NDArray:
            return np.concatenate([getattr(part, name) for part in parts])
        ranking = None
        if parts[0].ranking is not None:
            ranking = np.full((sum(map(len, parts)), max(part.ranking.shape[1] for part in parts)), -1, dtype=np.int64)
            ends = np.cumsum([len(part) for part in parts])
            for part, end in zip(parts, ends):
                ranking[end - len(part):end, :part.ranking.shape[1]] = part.ranking
        return cls(match=joined("match"), difference=joined("difference"), confidence=joined("confidence"),
                   stage=joined("stage"), ranking=ranking, **kwargs,
                   columns={name: np.concatenate([part.columns[name] for part in parts]) for name in parts[0].columns})
