"""FAB-MAP 1.0 (Cummins and Newman, IJRR 2008): the observation likelihood of each map place
through the Chow-Liu tree, the new-place likelihood, and the posterior over places.

Observation likelihood of a word-presence vector Z = (z_1 .. z_K) at place L_j:

    p(Z | L_j) = prod_q p(z_q | z_p(q), L_j)
    p(z_q | z_p, L_j) = sum_{e in {0,1}} p(z_q | e_q = e, z_p) p(e_q = e | L_j)
    p(z_q = s | e_q = e, z_p) = beta / (alpha + beta)
        alpha = p(z_q = s) p(z_q = !s | e_q = e) p(z_q = !s | z_p)
        beta  = p(z_q = !s) p(z_q = s | e_q = e) p(z_q = s | z_p)

with p(z_q | z_p) and p(z_q) from the Chow-Liu tree, p(z_q | e_q) the detector model and
p(e_q | L_j) the place's appearance model (wiloc/bow/fabmap/detector.py). At the root, which has no
parent, the tree's conditional is its marginal and the factor reduces to the detector model.

The factor ``c_q(e) = p(z_q | e_q = e, z_p)`` depends on the observation only, not on the place,
so one observation costs O(K) for the factors and then, per place, a sum of K logs of
``c_q(0) + (c_q(1) - c_q(0)) a_jq``. A place seen once has ``a_jq`` equal to one of two values
per word (the word seen or not), so the whole row over places seen once is a constant plus one
matrix-vector product of their 0/1 observations; places seen more often are computed exactly on
their own.

New place: ``sampled`` averages p(Z | L_u) over place models L_u made from training images (each
seen once); ``mean-field`` uses one average place with p(e_q = 1) = p(z_q = 1). Posterior over the
map places and the new place from their priors, then smoothed (`posterior`, shared with the
``fabmap`` method; parameters in `FabMapParams`).
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import logsumexp

from wiloc.bow.fabmap.chow_liu import ChowLiuTree
from wiloc.bow.fabmap.detector import Detector
from wiloc.bow.fabmap.params import FabMapParams
from wiloc.errors import ParameterError


def posterior(log_ratio: NDArray[np.floating], params: FabMapParams,
              log_prior: NDArray[np.float64] | None = None) -> tuple[NDArray[np.float64], float]:
    """(p(L_j | Z) per place, p(new place | Z)) from the evidence row r_j = log p(Z | L_j) -
    log p(Z | new place): FAB-MAP's posterior, the one the model and the ``fabmap`` method share.

    The candidate places (finite r_j; -inf: no candidate, posterior 0) share the prior
    ``1 - new_place_prior`` by ``log_prior`` (log weights summing to 1 over them; default equal
    shares), the new place has ``new_place_prior``. The normalised posterior is smoothed,
    p <- sigma p + (1 - sigma) / (candidates + 1) with sigma ``posterior_smoothing``, so no
    hypothesis is certain.
    """
    candidates = np.isfinite(log_ratio)
    n = int(candidates.sum())
    if n == 0:
        return np.zeros(len(log_ratio)), 1.0
    weights = -np.log(n) if log_prior is None else log_prior
    log_joint = np.where(candidates, log_ratio + np.log1p(-params.new_place_prior) + weights, -np.inf)
    log_new = np.log(params.new_place_prior)
    total = float(np.logaddexp(logsumexp(log_joint), log_new))
    sigma = params.posterior_smoothing
    places = np.where(candidates, sigma * np.exp(log_joint - total) + (1.0 - sigma) / (n + 1), 0.0)
    return places, sigma * float(np.exp(log_new - total)) + (1.0 - sigma) / (n + 1)


class _Places:
    """Place models stored as observation counts: ``positives[j, q]`` observations of place j
    showing word q out of ``observations[j]``; rows grow in amortised O(1)."""

    def __init__(self, n_words: int) -> None:
        self._positives = np.zeros((16, n_words), np.float64)
        self._observations = np.zeros(16, np.int64)
        self.count = 0

    @property
    def positives(self) -> NDArray[np.float64]:
        return self._positives[: self.count]

    @property
    def observations(self) -> NDArray[np.int64]:
        return self._observations[: self.count]

    def add(self, z: NDArray[np.bool_]) -> int:
        """A new place from its observations ``(m, K)``; returns its index."""
        if self.count == len(self._observations):
            self._positives = np.concatenate([self._positives, np.zeros_like(self._positives)])
            self._observations = np.concatenate([self._observations, np.zeros_like(self._observations)])
        self._positives[self.count] = 0.0
        self._observations[self.count] = 0
        self.count += 1
        self.update(self.count - 1, z)
        return self.count - 1

    def update(self, j: int, z: NDArray[np.bool_]) -> None:
        """Add observations ``(m, K)`` of place j."""
        self._positives[j] += z.sum(axis=0)
        self._observations[j] += len(z)


class FabMap:
    """FAB-MAP 1.0 over a fixed vocabulary: a map of places, each learned from its observations.

    ``tree``: the Chow-Liu tree of the training images' word occurrences. ``training``: those
    occurrences ``(N, K)`` bool, needed by the ``sampled`` new-place model.
    """

    def __init__(self, tree: ChowLiuTree, params: FabMapParams | None = None,
                 training: ArrayLike | None = None) -> None:
        self.tree = tree
        self.params = FabMapParams() if params is None else params
        self.detector = Detector(self.params.false_positive, self.params.false_negative)
        self._places = _Places(tree.n_words)
        self._source = np.where(tree.parent < 0, np.arange(tree.n_words), tree.parent)
        if self.params.new_place == "sampled":
            if training is None:
                raise ParameterError("new_place", "'sampled' needs the training occurrences (training=)")
            occurrences = self._check(training)
            n = min(self.params.samples, len(occurrences))
            chosen = np.random.default_rng(self.params.seed).choice(len(occurrences), n, replace=False)
            self.new_place_samples = occurrences[np.sort(chosen)].astype(np.float64)
        else:
            self.new_place_samples = np.zeros((0, tree.n_words))
        prior = tree.marginal
        self._seen = self.detector.appearance(1, 1, prior)  # p(e=1 | L) of a place seen once: word seen
        self._unseen = self.detector.appearance(1, 0, prior)  # ...: word not seen

    # -- the map ---------------------------------------------------------------------------

    @property
    def n_places(self) -> int:
        return self._places.count

    def add_place(self, z: ArrayLike) -> int:
        """Add a place from one observation ``(K,)`` or several of the same place ``(m, K)``
        (word presence, bool or 0/1); returns its index."""
        return self._places.add(self._check(z))

    def update_place(self, place: int, z: ArrayLike) -> None:
        """Learn more observations ``(K,)`` or ``(m, K)`` of an existing place."""
        if not 0 <= place < self.n_places:
            raise IndexError(f"place {place} not in the map of {self.n_places} places")
        self._places.update(place, self._check(z))

    def appearance(self, place: int) -> NDArray[np.float64]:
        """The place's appearance model p(e_q = 1 | L) over the words, ``(K,)``."""
        if not 0 <= place < self.n_places:
            raise IndexError(f"place {place} not in the map of {self.n_places} places")
        return self.detector.appearance(self._places.observations[place],
                                        self._places.positives[place], self.tree.marginal)

    # -- likelihoods ------------------------------------------------------------------------

    def word_factors(self, z: ArrayLike) -> NDArray[np.float64]:
        """``(2, K)``: ``c[e, q] = p(z_q | e_q = e, z_parent(q))`` for the observation ``z``."""
        s = self._check_one(z)
        zp = s[self._source]
        p_one = self.tree.marginal
        p_s = np.where(s, p_one, 1.0 - p_one)  # p(z_q = s_q)
        cond_one = self.tree.conditional[np.arange(s.size), zp.astype(np.intp)]
        p_s_parent = np.where(s, cond_one, 1.0 - cond_one)  # p(z_q = s_q | z_p)
        detect = self.detector.detection()[:, None]  # p(z=1 | e), e = 0, 1
        d_s = np.where(s[None, :], detect, 1.0 - detect)  # p(z_q = s_q | e)
        beta = (1.0 - p_s) * d_s * p_s_parent
        alpha = p_s * (1.0 - d_s) * (1.0 - p_s_parent)
        return beta / (alpha + beta)

    def _rows(self, factors: NDArray[np.float64], positives: NDArray[np.float64],
              observations: NDArray[np.int64]) -> NDArray[np.float64]:
        """log p(Z | L) of the places given by their counts, from the observation's factors."""
        c0, c1 = factors
        low = np.log(c0 + (c1 - c0) * self._unseen)
        high = np.log(c0 + (c1 - c0) * self._seen)
        rows = low.sum() + positives @ (high - low)  # exact for places seen once
        for j in np.flatnonzero(observations != 1):
            a = self.detector.appearance(observations[j], positives[j], self.tree.marginal)
            rows[j] = np.log(c0 + (c1 - c0) * a).sum()
        return rows

    def log_likelihoods(self, z: ArrayLike) -> NDArray[np.float64]:
        """``(places,)`` log p(Z | L_j) of the observation ``z`` ``(K,)`` at every map place."""
        return self._place_rows(self.word_factors(z))

    def new_place_log_likelihood(self, z: ArrayLike) -> float:
        """log p(Z | new place): sampled (log of the mean over the training place models) or
        mean-field (the average place)."""
        return self._new_place(self.word_factors(z))

    def frame_log_likelihoods(self, z: ArrayLike) -> tuple[NDArray[np.float64], float]:
        """Both of the above for one query frame, its word factors computed once: what an
        observation model needs per frame."""
        factors = self.word_factors(z)
        return self._place_rows(factors), self._new_place(factors)

    def _place_rows(self, factors: NDArray[np.float64]) -> NDArray[np.float64]:
        places = self._places
        return self._rows(factors, places.positives, places.observations)

    def _new_place(self, factors: NDArray[np.float64]) -> float:
        if self.params.new_place == "mean-field":
            c0, c1 = factors
            return float(np.log(c0 + (c1 - c0) * self.tree.marginal).sum())
        rows = self._rows(factors, self.new_place_samples, np.ones(len(self.new_place_samples), np.int64))
        return float(logsumexp(rows) - np.log(len(rows)))

    def posterior(self, z: ArrayLike, prior: ArrayLike | None = None
                  ) -> tuple[NDArray[np.float64], float]:
        """(p(L_j | Z) over the map places ``(places,)``, p(new place | Z)).

        ``prior``: relative prior weights of the map places (uniform when None), which share
        ``1 - new_place_prior``; the new place has ``new_place_prior`` (see :func:`posterior`).
        """
        n = self.n_places
        log_prior = None
        if prior is not None:
            weights = np.asarray(prior, dtype=np.float64)
            if weights.shape != (n,) or np.any(weights < 0) or not np.isfinite(weights).all() \
                    or (n and weights.sum() <= 0):
                raise ValueError(f"prior must be {n} finite non-negative weights, not all 0")
            with np.errstate(divide="ignore"):
                log_prior = np.log(weights / weights.sum()) if n else weights
        rows, new = self.frame_log_likelihoods(z)
        return posterior(rows - new, self.params, log_prior)

    def _check_one(self, z: ArrayLike) -> NDArray[np.bool_]:
        """One observation as ``(K,)`` bool."""
        if np.ndim(z) != 1:
            raise ValueError(f"one observation must be (K,); got shape {np.shape(z)}")
        return self._check(z)[0]

    def _check(self, z: ArrayLike) -> NDArray[np.bool_]:
        """Observation(s) as ``(m, K)`` bool."""
        array = np.asarray(z)
        if array.ndim == 1:
            array = array[None, :]
        if array.ndim != 2 or array.shape[1] != self.tree.n_words or len(array) == 0:
            raise ValueError(f"observations must be (K,) or (m, K) with K = {self.tree.n_words}; "
                             f"got shape {np.shape(z)}")
        if array.dtype != bool and not np.isin(array, (0, 1)).all():
            raise ValueError("observations must be word presence: bool or 0/1")
        return array.astype(bool)
