"""The online, training-free probability model (paper III.D and Appendix, SPEC.md section 4).

Each query frame's best match z and difference m = min d_k are decided with P(L | m) from two
histograms that the run fills itself, without labels: during initialisation the minima go to the
different-place histogram ``c``; afterwards each frame's minimum goes to the same-place histogram
``b`` and its smallest difference to a frame that is *not* the same place as z (``m_r``) goes to
``c``. The Appendix's recursive test, repaired and made iterative, decides which frames are the
same place as z. See docs/algorithm.md for every choice and the measurements behind the defaults.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np
from numpy.typing import NDArray

from wiloc.errors import UsageError, WilocError
from wiloc.methods.base import Decisions
from wiloc.model import HistogramModel, check_options

DEFAULT_INIT = 100
DEFAULT_BINS = 100
DEFAULT_EXCLUDE_RECENT = 10
DEFAULT_SAME_PLACE_WINDOW = 2
DEFAULT_SMOOTHING = 0.1
DEFAULT_PRIOR: float | None = None  # P(L) = the share of samples in b; docs/algorithm.md says why

Progress = Callable[[int, int], None]


def finite_minimum(row: NDArray[np.float64]) -> tuple[int, float]:
    """(argmin, min) over the finite entries of a difference row; (-1, nan) when there are none."""
    if row.size == 0:
        return -1, float("nan")
    z = int(np.argmin(row))
    m = float(row[z])
    return (z, m) if np.isfinite(m) else (-1, float("nan"))


def near_miss(row: NDArray[np.float64], z: int, match: NDArray[np.int64] | None,
              window: int) -> float:
    """m_r: the smallest difference in ``row`` to a frame that is not the same place as ``z``.

    The Appendix's recursive test, repaired and iterative. The same-place set M starts as z and
    the frames within +-``window`` of z (all skipped). Candidates are visited once in increasing
    difference; a candidate z_r joins M when ``match[z_r]`` is in M or ``match[min(M)] == z_r``
    (``match`` holds -1 for frames never decided, which never passes the test; ``None`` in map
    mode, where candidates are reference frames that are never decided). NaN when no candidate is
    left.
    """
    finite = np.flatnonzero(np.isfinite(row))
    order = finite[np.argsort(row[finite], kind="stable")]
    same = set(range(max(0, z - window), min(row.size, z + window + 1)))
    first = min(same)
    for cand in order.tolist():
        if cand in same:
            continue
        if match is not None:
            linked = match[cand]
            if (linked >= 0 and linked in same) or match[first] == cand:
                same.add(cand)
                first = min(first, cand)
                continue
        return float(row[cand])
    return float("nan")


def best_matches(rows: Iterable[NDArray[np.float64]], n_frames: int,
                 where: str) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Per row (argmin, min) over its finite entries: -1 and NaN for rows with no candidate."""
    best = [finite_minimum(np.asarray(row, dtype=np.float64)) for row in rows]
    if len(best) != n_frames:
        raise WilocError(where, f"got {len(best)} difference rows, expected n_frames={n_frames}")
    match = np.array([z for z, _ in best], dtype=np.int64).reshape(n_frames)
    difference = np.array([m for _, m in best], dtype=np.float64).reshape(n_frames)
    return match, difference


def model_from_values(values: NDArray[np.float64], bins: int, smoothing: float,
                      prior: float | None) -> HistogramModel:
    """An empty model whose ``bins`` equal bins span [min(0, lowest value), highest value].

    Differences are >= 0 for every metric, and same-place values fall below the samples that
    fix the range (different-place minima), so the low edge is 0, not the lowest value seen.
    """
    return HistogramModel.from_range(min(0.0, float(values.min())), float(values.max()), bins,
                                     smoothing=smoothing, prior=prior)


def _initial_model(seen: list[float], bins: int, smoothing: float,
                   prior: float | None) -> HistogramModel:
    """The model at the end of initialisation: range fixed from ``seen``, which fill ``c``."""
    values = np.asarray(seen, dtype=np.float64)
    model = model_from_values(values, bins, smoothing, prior)
    model.add_different(values)
    return model


def localize_online(
    rows: Iterable[NDArray[np.float64]],
    n_frames: int,
    *,
    sequence: bool,
    init: int = DEFAULT_INIT,
    bins: int = DEFAULT_BINS,
    same_place_window: int = DEFAULT_SAME_PLACE_WINDOW,
    prior: float | None = DEFAULT_PRIOR,
    smoothing: float = DEFAULT_SMOOTHING,
    init_rows: Iterable[NDArray[np.float64]] | None = None,
    progress: Progress | None = None,
) -> Decisions:
    """Localize each query frame with the online, training-free model (SPEC.md section 4).

    ``rows`` yields ``n_frames`` difference rows (np.inf = not a candidate). In sequence mode the
    first ``init`` frames that have a candidate only fill ``c``; in map mode ``init_rows`` (the
    reference traversal against itself outside +-R) fills ``c`` and every query frame is decided.
    The bin range is fixed from the initialisation minima; later values clamp into the edge bins.
    P(L) is ``prior`` (0.5 by default, SPEC.md section 3); None uses the share of samples in ``b``.
    """
    if init < 1:
        raise UsageError(None, f"--init must be >= 1, got {init}")
    if same_place_window < 0:
        raise UsageError(None, f"--same-place-window must be >= 0, got {same_place_window}")
    check_options(bins, smoothing, prior)
    if not sequence and init_rows is None:
        raise WilocError("online", "map mode needs init_rows: the reference traversal's "
                                   "difference rows against itself")

    match = np.full(n_frames, -1, dtype=np.int64)
    difference = np.full(n_frames, np.nan)
    confidence = np.full(n_frames, np.nan)
    m_r = np.full(n_frames, np.nan)
    stage = np.full(n_frames, "none", dtype="<U6")

    seen: list[float] = []
    if not sequence:
        seen = [m for _, m in map(finite_minimum, init_rows) if np.isfinite(m)]  # type: ignore[arg-type]
        if not seen:
            raise WilocError("online", "init_rows hold no finite difference")
    model = None if sequence else _initial_model(seen, bins, smoothing, prior)
    recorded = match if sequence else None

    k = -1
    for k, row in enumerate(rows):
        if k >= n_frames:
            raise WilocError("online", f"more difference rows than n_frames={n_frames}")
        row = np.asarray(row, dtype=np.float64)
        z, m = finite_minimum(row)
        if z >= 0 and model is None:
            stage[k] = "init"
            seen.append(m)
            if len(seen) == init:
                model = _initial_model(seen, bins, smoothing, prior)
        elif z >= 0:
            assert model is not None
            stage[k] = "update"
            confidence[k] = float(model.posterior(m))
            model.add_same(m)
            m_r[k] = near_miss(row, z, recorded, same_place_window)
            if np.isfinite(m_r[k]):
                model.add_different(m_r[k])
            match[k], difference[k] = z, m
        if progress is not None:
            progress(k + 1, n_frames)
    if k + 1 != n_frames:
        raise WilocError("online", f"got {k + 1} difference rows, expected n_frames={n_frames}")
    if model is None and seen:
        model = _initial_model(seen, bins, smoothing, prior)

    params = {"method": "online", "sequence": sequence, "init": init, "bins": bins,
              "same_place_window": same_place_window, "prior": prior, "smoothing": smoothing,
              "init_frames": len(seen)}
    return Decisions(match=match, difference=difference, confidence=confidence, stage=stage,
                     columns={"m_r": m_r}, model=model, params=params)
