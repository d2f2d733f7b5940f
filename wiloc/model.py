"""The histogram probability model P(L | d) of the paper's section III.B.

Two histograms over the same bins of the difference d: ``b`` counts same-place samples
(d and L), ``c`` counts different-place samples (d and not L). Values outside the bin range are
clamped into the edge bins. Empty bins never give 0/0: every bin gets an additive pseudo-count
``smoothing`` before normalising (see docs/algorithm.md for the choice).

In the paper's terms: ``b`` and ``c`` are the frequency-based P(d and L) and P(d and not L) of
Figure 1 (the Appendix's bins b_m and c_m), each over s bins as eq. 4 bins P(d); a bin's share
is P(d | L) or P(d | not L) (eq. 5), P(d) is their marginal (eq. 6) and :meth:`HistogramModel.posterior`
is P(L | d) by Bayes' rule (eq. 2).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from wiloc.reprs import brief


@dataclass
class HistogramModel:
    """Same-place (``b``) and different-place (``c``) histograms over fixed bin edges."""

    edges: NDArray[np.float64]
    smoothing: float = 1.0
    prior: float | None = None
    b: NDArray[np.float64] = field(default=None)  # type: ignore[arg-type]
    c: NDArray[np.float64] = field(default=None)  # type: ignore[arg-type]

    def __post_init__(self) -> None:
        self.edges = np.asarray(self.edges, dtype=np.float64)
        if self.edges.ndim != 1 or self.edges.size < 2 or np.any(np.diff(self.edges) <= 0):
            raise ValueError("edges must be a strictly increasing 1-D array of at least 2 values")
        if self.b is None:
            self.b = np.zeros(self.n_bins, dtype=np.float64)
        if self.c is None:
            self.c = np.zeros(self.n_bins, dtype=np.float64)
        self.b = np.asarray(self.b, dtype=np.float64)
        self.c = np.asarray(self.c, dtype=np.float64)
        for name, counts in (("b", self.b), ("c", self.c)):  # a results header edited by hand
            if counts.shape != (self.n_bins,) or not np.all(np.isfinite(counts) & (counts >= 0)):
                raise ValueError(f"{name} must hold a count >= 0 for each of the {self.n_bins} bins")

    def __repr__(self) -> str:
        """One line, as the other objects wiloc returns print (``wiloc.reprs``): the bins, their
        range and the samples counted so far, not the edges and counts whole (hundreds of values)."""
        return (f"HistogramModel(bins={self.n_bins}, range=({brief(self.edges[0])}, {brief(self.edges[-1])}), "
                f"same={brief(self.b.sum())}, different={brief(self.c.sum())}, smoothing={brief(self.smoothing)}, "
                f"prior={brief(self.prior)})")

    @classmethod
    def from_range(cls, low: float, high: float, bins: int = 100, **kwargs: float | None) -> HistogramModel:
        """A model with ``bins`` equal bins spanning [low, high]."""
        if bins < 1:
            raise ValueError(f"bins must be >= 1, got {bins}")
        if not high > low:
            high = low + max(abs(low), 1.0) * 1e-6
        return cls(np.linspace(low, high, bins + 1), **kwargs)  # type: ignore[arg-type]

    @classmethod
    def from_values(cls, values: NDArray[np.float64], bins: int, **kwargs: float | None) -> HistogramModel:
        """An empty model whose ``bins`` equal bins span [min(0, lowest value), highest value].

        Differences are >= 0 for every metric, and same-place values fall below the samples that
        fix the range (different-place minima), so the low edge is 0, not the lowest value seen.
        """
        return cls.from_range(min(0.0, float(values.min())), float(values.max()), bins, **kwargs)

    @property
    def n_bins(self) -> int:
        return int(self.edges.size - 1)

    def bin_of(self, d: ArrayLike) -> NDArray[np.intp]:
        """Bin index of each difference, clamped into [0, n_bins - 1]."""
        idx = np.searchsorted(self.edges, np.asarray(d, dtype=np.float64), side="right") - 1
        return np.clip(idx, 0, self.n_bins - 1)

    def add_same(self, d: ArrayLike) -> None:
        """Count difference(s) as same-place samples (``b``)."""
        np.add.at(self.b, self.bin_of(np.atleast_1d(d)), 1.0)

    def add_different(self, d: ArrayLike) -> None:
        """Count difference(s) as different-place samples (``c``)."""
        np.add.at(self.c, self.bin_of(np.atleast_1d(d)), 1.0)

    def count_bins(self, same: int, different: int | None = None) -> None:
        """Count one same-place sample (and one different-place sample) by its bin
        (:meth:`bin_of`, taken ahead): what :meth:`add_same` and :meth:`add_different` count."""
        self.b[same] += 1.0
        if different is not None:
            self.c[different] += 1.0

    def _density(self, counts: NDArray[np.float64]) -> NDArray[np.float64]:
        smoothed = counts + self.smoothing
        total = smoothed.sum()
        if total <= 0:
            return np.full(self.n_bins, 1.0 / self.n_bins)
        return smoothed / total

    def p_d_given_same(self, d: ArrayLike) -> NDArray[np.float64]:
        """P(d | L) per value: the smoothed share of ``b`` in the value's bin."""
        return self._density(self.b)[self.bin_of(d)]

    def p_d_given_different(self, d: ArrayLike) -> NDArray[np.float64]:
        """P(d | not L) per value: the smoothed share of ``c`` in the value's bin."""
        return self._density(self.c)[self.bin_of(d)]

    def prior_same(self) -> float:
        """P(L): the configured prior, else the share of samples in ``b`` (0.5 when both empty)."""
        if self.prior is not None:
            return float(self.prior)
        nb, nc = float(self.b.sum()), float(self.c.sum())
        return 0.5 if nb + nc == 0 else nb / (nb + nc)

    def posterior(self, d: ArrayLike) -> NDArray[np.float64]:
        """P(L | d) by Bayes' rule (paper eq. 2 with the marginal of eq. 6)."""
        prior = self.prior_same()
        same = self.p_d_given_same(d) * prior
        diff = self.p_d_given_different(d) * (1.0 - prior)
        return same / (same + diff)

    def to_dict(self) -> dict[str, list[float] | float | None]:
        """Plain lists for saving the model with a run."""
        return {"edges": self.edges.tolist(), "b": self.b.tolist(), "c": self.c.tolist(),
                "smoothing": self.smoothing, "prior": self.prior}

    @classmethod
    def from_dict(cls, data: dict) -> HistogramModel:
        return cls(np.asarray(data["edges"]), smoothing=float(data.get("smoothing", 1.0)),
                   prior=data.get("prior"), b=np.asarray(data["b"]), c=np.asarray(data["c"]))
