"""FAB-MAP's detector model p(z | e) and the place appearance model p(e = 1 | L) it implies.

Every word q has a hidden scene element e_q (present at the place or not) and an observation
z_q (the word detected in the image or not). The detector model, the same for every word and
place, is two numbers: p(z = 1 | e = 0), the false-positive rate, and p(z = 0 | e = 1), the
false-negative rate.

A place's appearance model p(e_q = 1 | L_j) starts from the prior p(e_q = 1), taken as the
training marginal p(z_q = 1) (as openFABMAP does), and is updated by Bayes' rule with the
detector model for each observation of the place (FAB-MAP 1.0's place update, which treats the
words of one observation as independent given e). The update is commutative, so after n
observations of which k show the word:

    p(e=1 | L) = rho (1-fn)^k fn^(n-k) / (rho (1-fn)^k fn^(n-k) + (1-rho) fp^k (1-fp)^(n-k))

With the default fp = 0 a word seen once at a place is certainly there (p = 1); a word never
seen keeps a small probability, rho fn^n / (rho fn^n + 1 - rho).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class Detector:
    """The detector model: ``false_positive`` p(z=1|e=0), ``false_negative`` p(z=0|e=1)
    (validated by `FabMapParams`)."""

    false_positive: float
    false_negative: float

    def detection(self) -> NDArray[np.float64]:
        """``[p(z=1 | e=0), p(z=1 | e=1)]``."""
        return np.array([self.false_positive, 1.0 - self.false_negative])

    def appearance(self, observations: ArrayLike, positives: ArrayLike,
                   prior: ArrayLike) -> NDArray[np.float64]:
        """p(e = 1 | L) after ``observations`` (n) observations of which ``positives`` (k) show
        the word, from the prior p(e = 1) ``prior`` (rho); the three broadcast together."""
        n = np.asarray(observations, dtype=np.float64)
        k = np.asarray(positives, dtype=np.float64)
        rho = np.asarray(prior, dtype=np.float64)
        fp, fn = self.false_positive, self.false_negative
        with np.errstate(divide="ignore", invalid="ignore"):
            # k * log(0) is -inf for k > 0 and must be 0 for k = 0 (0^0 = 1).
            seen_absent = np.where(k > 0, k * np.log(fp), 0.0)
            present = np.log(rho) + k * np.log1p(-fn) + (n - k) * np.log(fn)
            absent = np.log1p(-rho) + seen_absent + (n - k) * np.log1p(-fp)
        return np.exp(present - np.logaddexp(present, absent))
