"""Aligned ground truth (SPEC.md section 7): traversals recorded frame by frame along the same
route, where the same file name (or a video's frame index) is the same place, +-T reference frames
along the route; see docs/evaluation.md, "aligned"."""
from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from wiloc.errors import WilocError
from wiloc.evaluation.groundtruth import (LeftOut, Truth, TruthMismatch, band, check_tolerance, frame_indices, lookup,
                                          past_left_out, position_spans, truth_from_pairs)
from wiloc.evaluation.truth_warnings import query_frames_without


def _nearest_index(query: NDArray[np.int64], ref: NDArray[np.int64]) -> NDArray[np.int64]:
    """The reference frame whose index is nearest each query index (the lower one on a tie): the
    same frame when the reference holds it, the nearest one kept when the reference was sampled;
    -1 beyond half the reference's usual step past either end."""
    order = np.argsort(ref, kind="stable")
    ordered = ref[order]
    after = np.clip(np.searchsorted(ordered, query), 0, ordered.size - 1)
    before = np.clip(after - 1, 0, ordered.size - 1)
    pick = np.where(np.abs(ordered[after] - query) < np.abs(query - ordered[before]), after, before)
    reach = float(np.median(np.diff(ordered))) / 2 if ordered.size > 1 else 0.0
    return np.where((query >= ordered[0] - reach) & (query <= ordered[-1] + reach), order[pick], -1)


_NUMBERED = re.compile(r"(.*?)([0-9]+)([^0-9]*)", re.DOTALL)
"""A name as the text before its last number, that number and the text after it."""


def _name_numbers(names: Sequence[str], like: str) -> NDArray[np.int64]:
    """The number in each name written as ``like`` is (the same text around its last number:
    ``Image058.jpg`` as ``Image100.jpg``), -1 in other names and numbers too long for int64."""
    form = _NUMBERED.fullmatch(like)
    parts = [_NUMBERED.fullmatch(name) for name in names]
    return np.array([int(m[2]) if form and m and len(m[2]) <= 18 and (m[1], m[3]) == (form[1], form[3]) else -1
                     for m in parts], dtype=np.int64)


def _numbers(names: Sequence[str], by: Literal["name", "index"], like: str) -> NDArray[np.int64]:
    """The numbers that place frames along the route: by index the frames' indices
    (:func:`frame_indices`), by name the number each name holds written as ``like`` is."""
    return frame_indices(names) if by == "index" else _name_numbers(names, like)


def _route(numbers: NDArray[np.int64], query: NDArray[np.int64], by: str) -> tuple[NDArray[np.int64], int] | None:
    """The reference's ``numbers``, which count its frames along the route, and one frame's step,
    where they rise at a regular step that leaves frames out: every step a multiple of the
    smallest, and one more than twice it (a gap), or, by name (files of a folder), a few twice it
    (fewer than one step in ten: single files deleted) at which the ``query`` (its frames'
    numbers) holds the frame the map lacks. None otherwise, where frames are counted in the
    reference's order: stamps, names without a number, a map that leaves nothing out (the same
    count), traversals sampled alike (the query lacks the same frames) and a video sampled at a
    rate that is no whole part of its own (20 or 25 of 30 frames a second: one step in two or in
    five twice the smallest, a map frame counting 1.5 or 1.2 of its numbers)."""
    steps = np.diff(numbers)
    if numbers.size < 2 or (numbers < 0).any() or (steps <= 0).any():
        return None
    step = int(steps.min())
    if (steps % step).any():
        return None
    larger = steps > step
    few = by == "name" and 10 * larger.sum() < steps.size and _falls_in(query, numbers, larger).any()
    leaves_out = (steps > 2 * step).any() or few
    return (numbers, step) if leaves_out else None


def _falls_in(query: NDArray[np.int64], numbers: NDArray[np.int64], steps: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Whether each ``query`` number lies strictly inside one of the ascending ``numbers``' steps
    marked in ``steps`` (one per consecutive pair)."""
    after = np.searchsorted(numbers, query, side="left")
    inside = (after > 0) & (after < numbers.size) & (numbers[np.minimum(after, numbers.size - 1)] != query)
    return inside & steps[np.clip(after - 1, 0, steps.size - 1)]


def _route_spans(centres: NDArray[np.int64], own: NDArray[np.int64], route: NDArray[np.int64], step: int,
                 tolerance: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The reference frames (first, stop) whose numbers lie within +-T steps of each query frame's
    place on the route: its centre's number, where the centre lies within half a step of the
    query frame's ``own`` number, else, for a query frame in a gap the reference leaves (within
    its ends, no frame within half a step), its own number; none otherwise."""
    nearest = _nearest_index(own, route)
    in_gap = (own >= route[0]) & (own <= route[-1]) & (2 * np.abs(route[nearest] - own) > step)
    centred = (centres >= 0) & (2 * np.abs(route[centres] - own) <= step)
    place = np.where(centred, route[centres], own)
    reach = min(tolerance * step, int(route[-1] - route[0]) + 1)  # wider than the route is all of it, and fits int64
    first = np.searchsorted(route, place - reach, side="left").astype(np.int64)
    return first, np.where(centred | in_gap, np.searchsorted(route, place + reach, side="right"), first)


def aligned_truth(query_names: Sequence[str], ref_names: Sequence[str], tolerance: int,
                  by: Literal["name", "index"] = "name", left_out: LeftOut = ()) -> Truth:
    """Aligned traversals: the same file name (or index, :func:`frame_indices`) is the same
    place, +-T reference frames along the route.

    Used when traversals were recorded frame by frame along the same route (Gardens Point,
    Nordland). ``tolerance`` counts frames by the numbers the reference's frames carry where
    they are numbered at a regular step (:func:`_route`), so that the band does not reach across
    frames the reference leaves out, and a query frame among those is true against the frames
    within +-T of its own number; else frames in the reference's order, its frames ``left_out``
    (unreadable, :data:`LeftOut`) counted too, so that one left out shifts no band.
    """
    if left_out:
        return past_left_out(ref_names, left_out, lambda full: aligned_truth(query_names, full, tolerance, by))
    tol = min(check_tolerance(tolerance), len(ref_names))  # wider than the map is the whole map, and fits int64
    where = f"aligned ground truth (by {by})"
    n_query = len(query_names)
    if by == "name":
        centres = lookup(query_names, ref_names)
    elif by == "index":
        centres = (_nearest_index(frame_indices(query_names), frame_indices(ref_names)) if len(ref_names)
                   else np.full(n_query, -1, dtype=np.int64))
    else:
        raise WilocError(None, f"aligned ground truth: by must be 'name' or 'index', got {by!r}")
    like = ref_names[0] if len(ref_names) else ""
    own = _numbers(query_names, by, like)
    if (route := _route(_numbers(ref_names, by, like), own, by)) is None:
        first, stop = position_spans(centres, tol, len(ref_names))
    else:
        first, stop = _route_spans(centres, own, *route, tol)
    found = stop > first
    if not found.any():
        raise TruthMismatch(where, f"none of the {n_query} query frames has a reference frame "
                                + ("of the same name (to align by position, as a video's frames with a folder's: "
                                   "aligned:index, by='index')" if by == "name"
                                   else "at its position"))
    warnings = query_frames_without(where, ~found, "query frames have no reference frame to align with")
    rows, cols = band(np.flatnonzero(found).astype(np.int64), first[found], stop[found])
    return truth_from_pairs(rows, cols, query_names, ref_names, warnings)
