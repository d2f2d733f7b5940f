"""What one localization run looked like, rebuilt from its results file for a figure: the
difference matrix reduced to a picture with the decided matches and the ground truth, the run's
timeline (matches, confidences and P(new place) frame by frame), and example matched image pairs
(the most confident right and wrong ones).

The descriptors come back through the cache from what the results header names (the query and
map traversals, the descriptor and its parameters, a video's sampling), so nothing is described
again; the differences are computed block by block, as the run computed them. A header whose traversals no longer give the frames
the file lists is an error naming the file.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from wiloc.errors import ParameterError, WilocError
from wiloc.reprs import short_repr

if TYPE_CHECKING:
    from wiloc.cache.store import Cache, Entry
    from wiloc.evaluation.comparison import Evaluation

#: The most pixels a side of the matrix picture gets; larger matrices are min-pooled to it.
MAX_SIDE = 800
#: The most example pairs of each kind (right, wrong) drawn, a row of images each: a figure's
#: cost grows faster than its rows (50 of each on Gardens Point: 26,000 pixels tall, 18 s and
#: 1 GB; a few hundred took minutes), and 20 of each is already more than a page shows.
MAX_PAIRS = 20


@short_repr
@dataclass(frozen=True)
class MatrixPicture:
    """A run's difference matrix for display: ``image`` holds the smallest difference of each block
    of (query, reference) cells (inf where no cell is a candidate), ``shape`` the full matrix's
    size; the ground truth's true pairs and each query frame's match, correctness and confidence
    are in full-matrix coordinates."""

    image: NDArray[np.float64]
    shape: tuple[int, int]
    truth_rows: NDArray[np.int64]
    truth_cols: NDArray[np.int64]
    match: NDArray[np.int64]
    correct: NDArray[np.bool_]
    confidence: NDArray[np.float64]
    query: str
    reference: str
    descriptor: str


@short_repr
@dataclass(frozen=True)
class ImagePair:
    """One decided match to show: the query image, the map image it matched and, for a wrong match
    of a frame that has a true place, that place's image (the middle of its true frames); ``frame``
    is the query frame's number in the run (from 0, in the run's order; None: not known)."""

    query_name: str
    match_name: str
    truth_name: str | None
    confidence: float
    correct: bool
    query_image: NDArray[np.uint8]
    match_image: NDArray[np.uint8]
    truth_image: NDArray[np.uint8] | None
    frame: int | None = None


@short_repr
@dataclass(frozen=True)
class Timeline:
    """A run frame by frame: each query frame's match (-1: undecided), whether it is right, its
    confidence (NaN: undecided) and P(new place) (None: the run gives none), whether the frame has
    a true match in the map, and the ground truth's true (query, map) pairs, counted from the
    first frame shown; ``first`` is that frame's number in the run (a slice's start, ``--frames``),
    from which the figure numbers the frames."""

    match: NDArray[np.int64]
    correct: NDArray[np.bool_]
    confidence: NDArray[np.float64]
    new_place: NDArray[np.float64] | None
    has_match: NDArray[np.bool_]
    truth_rows: NDArray[np.int64]
    truth_cols: NDArray[np.int64]
    first: int = 0


def run_timeline(evaluation: Evaluation) -> Timeline:
    """The run's timeline, from its results and ground truth (no images, no descriptors): of the
    frames scored, numbered as the run numbers them."""
    coo = evaluation.truth.matrix.tocoo()
    new_place = evaluation.results.new_place
    return Timeline(match=evaluation.results.match_index, correct=evaluation.correct,
                    confidence=evaluation.confidence,
                    new_place=None if new_place is None else np.asarray(new_place, dtype=np.float64),
                    has_match=np.asarray(evaluation.truth.has_match(), dtype=np.bool_),
                    truth_rows=coo.row.astype(np.int64), truth_cols=coo.col.astype(np.int64),
                    first=evaluation.first_frame)


def true_places(evaluation: Evaluation) -> NDArray[np.int64]:
    """Per query frame, the map frame shown as its true place: the middle of its true frames
    (-1 for a frame without a true match)."""
    truth = evaluation.truth.matrix.tocsr()
    place = np.full(truth.shape[0], -1, dtype=np.int64)
    for k in range(truth.shape[0]):
        true = np.sort(truth.indices[truth.indptr[k]:truth.indptr[k + 1]])
        if true.size:
            place[k] = true[true.size // 2]
    return place


def run_traversals(evaluation: Evaluation) -> tuple[Path, Path, bool]:
    """(query, reference, sequence mode) as the results header names them: a WilocError when it
    names none (a live run saved without its query), whose images no figure can show (an empty
    name would be the current folder, described in their place)."""
    header = evaluation.results.header
    for role, folder in (("query", header.query), ("map", header.sequence or header.map)):
        if not folder:
            raise WilocError(evaluation.path or evaluation.name,
                             f"the run records no {role} folder (a live run saved without one: "
                             f"Localizer.results(query=FOLDER) records it), so its images cannot be shown")
    query = Path(header.query)
    return query, query if header.sequence else Path(header.map), header.sequence


def checked_entries(evaluation: Evaluation, cache: Cache) -> tuple[Entry, Entry]:
    """The query's and the map's descriptors, through the cache, checked against the file's frames
    and against the digests the run recorded of them: a WilocError naming the folder whose images
    are no longer the run's (changed, or another folder of the same names), so that no figure
    shows other images than the run's. For a run scored on a slice of its frames (``--frames``)
    the query's entry is the whole run's, whose slice must be the frames the file lists."""
    from wiloc.description.traversals import Describer, descriptors_digest
    from wiloc.evaluation.run_frames import check_frames
    from wiloc.sources.video import Sampling

    header = evaluation.results.header
    label = "sad" if header.descriptor is None else header.descriptor
    descriptor, _, metric = label.partition(":")  # external:METRIC, an imported matrix
    describer = Describer(descriptor, dict(header.descriptor_params), cache, metric=metric or None,
                          sampling=None if header.sampling is None else Sampling(**header.sampling),
                          topic=header.topic)
    query, reference, sequence = run_traversals(evaluation)
    results = evaluation.results
    scored = results.frames["frame"].tolist()
    for folder in dict.fromkeys((query, reference)):  # named with the run it is missing from
        if not folder.exists():
            raise WilocError(evaluation.path, f"its traversal {folder} does not exist (moved or deleted); cannot "
                                              "draw it")
    q = describer.entry(query)
    frames = check_frames(evaluation.frame_slice)  # a run scored on a slice lists those of its frames
    q = _first_frames(q, scored if frames is None else q.names[:evaluation.run_frames])
    map_describer = describer if header.map_topic is None else replace(describer, topic=header.map_topic)
    r = q if sequence else map_describer.entry(reference)
    for role, entry, names, listed in (("query", q, q.names if frames is None else q.names[frames], scored),
                                       ("map", r, r.names, results.reference_frames)):
        if listed and names != listed:
            raise WilocError(evaluation.path, f"its {role} {entry.folder} no longer gives the frames it lists "
                                              f"({_changes(listed, names, Path(entry.folder))}); cannot draw it")
    for role, entry in (("query", q), ("map", r)):
        recorded = header.query_digest if role == "query" else header.map_digest  # batch runs record them
        if recorded and recorded != descriptors_digest(entry.names, entry.data):
            raise WilocError(evaluation.path, f"its {role} {entry.folder} no longer gives the descriptors the run "
                                              "used (its images changed, or it is another folder of the same "
                                              "names); cannot draw it")
    return q, r


def _first_frames(entry: Entry, listed: list[str]) -> Entry:
    """The query's entry cut to the frames the run lists when they are its first ones (a live run
    stopped before the folder's end, a folder that has grown since): those are the run's frames,
    checked as any; other lists are left whole for the check to name what changed."""
    if len(listed) >= len(entry.names) or entry.names[:len(listed)] != listed:
        return entry
    n = len(listed)
    return replace(entry, names=list(listed), data=entry.data[:n],
                   timestamps_ms=None if entry.timestamps_ms is None else entry.timestamps_ms[:n])


def _changes(listed: list[str], names: list[str], folder: Path) -> str:
    """How a traversal's frames differ from those a results file lists, in a few words: the
    frames gone, those whose file in ``folder`` is still there but no longer reads, and the new
    ones (the first three of each), or their order."""
    have, had = set(names), set(listed)
    lost, new = [n for n in listed if n not in have], [n for n in names if n not in had]
    if not lost and not new:
        return "the same frames in another order"
    if len(lost) == len(listed):
        return "none of its frames is there: another folder, or the run took its frame names from a file"
    unreadable = [n for n in lost if (folder / n).is_file()]
    gone = [n for n in lost if n not in unreadable]

    def some(items: list[str]) -> str:
        return ", ".join(items[:3]) + (f" and {len(items) - 3} more" if len(items) > 3 else "")
    return "; ".join(f"{some(items)} {what}" for items, what in ((gone, "gone"), (unreadable, "unreadable now"),
                                                                  (new, "new")) if items)


def _pooled(rows: NDArray[np.float64], factor: int) -> NDArray[np.float64]:
    """The minimum of each run of ``factor`` columns (the last run may be shorter)."""
    pad = (-rows.shape[-1]) % factor
    padded = np.pad(rows, (0, pad), constant_values=np.inf) if pad else rows
    return padded.reshape(-1, factor).min(axis=1)


def matrix_picture(evaluation: Evaluation, cache: Cache, max_side: int = MAX_SIDE) -> MatrixPicture:
    """The run's difference matrix, min-pooled to at most ``max_side`` pixels a side (memory:
    one block of rows), with its matches and ground truth."""
    from wiloc.candidates import mask_recent
    from wiloc.description.differences import differences

    if evaluation.frame_slice is not None:
        raise WilocError(evaluation.path, f"drawn for the whole run only, and frames {evaluation.frame_slice} "
                                          f"of its {evaluation.run_frames} were scored")
    q, r = checked_entries(evaluation, cache)
    _, _, sequence = run_traversals(evaluation)
    exclude = evaluation.results.header.exclude_recent
    n_query, n_ref = len(q.names), len(r.names)
    fy, fx = math.ceil(n_query / max_side), math.ceil(n_ref / max_side)
    image = np.empty((math.ceil(n_query / fy), math.ceil(n_ref / fx)))
    matrix = differences(q, r)  # computed block by block, never stored
    for i, start in enumerate(range(0, n_query, fy)):
        block = matrix.rows(start, min(start + fy, n_query)).astype(np.float64)
        if sequence:
            for k in range(block.shape[0]):
                mask_recent(block[k], start + k, exclude)
        image[i] = _pooled(block.min(axis=0), fx)
    coo = evaluation.truth.matrix.tocoo()
    return MatrixPicture(image=image, shape=(n_query, n_ref), truth_rows=coo.row.astype(np.int64),
                         truth_cols=coo.col.astype(np.int64), match=evaluation.results.match_index,
                         correct=evaluation.correct, confidence=evaluation.confidence,
                         query=Path(q.folder).name, reference=Path(r.folder).name,
                         descriptor=evaluation.results.header.descriptor or "")


def read_rgb(path: Path) -> NDArray[np.uint8]:
    """An image file in colour (RGB), else as read_gray reads it (which names a bad file)."""
    import cv2

    from wiloc.sources.frames import decode, read_gray

    colour = decode(np.fromfile(path, np.uint8), cv2.IMREAD_COLOR, path) if path.is_file() else None
    if colour is None:
        return read_gray(path)
    return cv2.cvtColor(colour, cv2.COLOR_BGR2RGB)


def unchecked_folders(evaluation: Evaluation) -> list[str]:
    """A line naming the folders whose images the run recorded no digest of (a followed run's, a
    file of an older version), none when it recorded them: a figure shows those folders as they
    are now, which :func:`checked_entries` cannot tell from the run's."""
    query, reference, sequence = run_traversals(evaluation)
    roles = (("query", query),) if sequence else (("query", query), ("map", reference))
    header = evaluation.results.header
    recorded = {"query": header.query_digest, "map": header.map_digest}
    folders = [str(folder) for role, folder in roles if recorded[role] is None]
    if not folders:
        return []
    return [f"{evaluation.path or evaluation.name}: the run recorded no digest of its images, so figures show "
            f"{' and '.join(folders)} as {'they are' if len(folders) > 1 else 'it is'} now, unchecked"]


def example_pairs(evaluation: Evaluation, count: int = 3, wrong_only: bool = False, *,
                  cache: Cache | None = None) -> list[ImagePair]:
    """Up to ``count`` most confident right matches (none with ``wrong_only``), then up to
    ``count`` most confident wrong ones, of the frames scored (a slice's, ``--frames``, numbered as
    the run numbers them), with their images read from the folders the results header names, once
    :func:`checked_entries` (through ``cache``, default the user's) finds them the run's. At most
    MAX_PAIRS of each: a row of images each, the figure's cost grows faster than its rows."""
    from wiloc.cache.store import Cache

    if not 1 <= count <= MAX_PAIRS:
        raise ParameterError("count", f"must be from 1 to {MAX_PAIRS} pairs of each kind, got {count}")
    query, reference, _ = run_traversals(evaluation)
    for folder in dict.fromkeys((query, reference)):
        if not folder.is_dir():
            raise WilocError(evaluation.path, f"example images need the image folders the run named; {folder} "
                                              "is not a folder")
    checked_entries(evaluation, cache if cache is not None else Cache())
    results = evaluation.results
    names, ref_names = results.frames["frame"].tolist(), results.reference_frames or results.frames["frame"].tolist()
    match, confidence, correct = results.match_index, evaluation.confidence, evaluation.correct
    decided = np.flatnonzero((match >= 0) & np.isfinite(confidence))
    by_confidence = decided[np.argsort(-confidence[decided], kind="stable")]
    right = [] if wrong_only else [k for k in by_confidence if correct[k]][:count]
    chosen = [*right, *[k for k in by_confidence if not correct[k]][:count]]
    place = true_places(evaluation)
    pairs = []
    for k in chosen:
        truth_name = ref_names[place[k]] if not correct[k] and place[k] >= 0 else None
        pairs.append(ImagePair(
            query_name=names[k], match_name=ref_names[match[k]], truth_name=truth_name,
            confidence=float(confidence[k]), correct=bool(correct[k]),
            query_image=read_rgb(query / names[k]), match_image=read_rgb(reference / ref_names[match[k]]),
            truth_image=read_rgb(reference / truth_name) if truth_name else None,
            frame=evaluation.first_frame + int(k)))
    return pairs
