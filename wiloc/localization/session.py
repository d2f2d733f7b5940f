"""One localization run's setup, shared by batch and streaming runs.

``RunSession`` makes the method, checks its inputs, describes the query (a batch run's) and the
map and checks their sizes, chooses the row kind (differences, or FAB-MAP's evidence), reads
odometry and the training pair, and builds the ``MapContext`` the method starts on. It then
gives the rows the method decides from: :meth:`RunSession.batch_rows`, the whole query's rows
that ``wiloc.api.localize`` feeds ``method.run``, or :meth:`RunSession.row`, one frame's row that
``wiloc.Localizer`` steps (and :meth:`RunSession.add` grows sequence mode's candidates with).
A new method input or row kind is added here once, for both.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import asdict, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.cache.store import Cache, Entry
from wiloc.candidates import DEFAULT_EXCLUDE_RECENT, check_exclude_recent, mask_recent
from wiloc.description.describing import check_sampling, check_topic, is_bag, is_stream, left_out
from wiloc.description.differences import ComputedDifferences, RunDifferences, candidate_blocks, run_differences, summarize
from wiloc.description.distances import DifferencesTo, consecutive, pairwise
from wiloc.description.traversals import (Describer, Progress, check_descriptor, check_metric, descriptor_spec,
                                         descriptors_digest, entry_params, is_matrix_file, open_cluster, stage)
from wiloc.errors import ParameterError, UsageError, WilocError, parameter_values
from wiloc.localization.odometry import bag_odometry, read_odometry, traversal_arclength, traversal_steps
from wiloc.localization.training import Training, training_rows
from wiloc.methods.base import MapContext, Method, TrainingRows
from wiloc.methods.registry import learning_from_the_map, make_method
from wiloc.sources.video import Sampling

#: The labelled pair of ``trained``: its traversals and truth, or their difference rows and labels.
TrainingPair = Training | TrainingRows

#: What a query or map is, as errors about one say it.
TRAVERSAL = "one traversal (a folder, video, ROS bag or descriptor matrix file)"


def check_traversal(value: object, parameter: str, also: str = "", hint: str = "", what: str = TRAVERSAL) -> None:
    """Refuse, as a ParameterError naming ``parameter``, a ``value`` that is not one traversal's
    path (text or a path object): a list of several, an array of descriptors, None, an empty path
    or one holding NUL. ``also`` says what else the parameter takes, ``hint`` what to do with
    several; ``what`` is the path taken when it is another file's (an odometry CSV)."""
    if not isinstance(value, (str, os.PathLike)):
        several = hint if isinstance(value, (list, tuple)) else ""
        raise ParameterError(parameter, f"{what}{also}, got {type(value).__name__}{several}")
    text = os.fsdecode(value)
    if not text:  # Path("") is the current folder: say what was given instead
        raise ParameterError(parameter, "the path is empty")
    if "\0" in text:  # no file's name holds one; the system would refuse it as a ValueError
        raise ParameterError(parameter, "the path holds a NUL character; no file is named so")


def _map_descriptor(map: str | os.PathLike | Entry | None, descriptor: str | None,
                    params: Mapping[str, Any] | None) -> tuple[str, Mapping[str, Any] | None]:
    """The descriptor and parameters a run describes frames with: those given (None: ``sad``); for
    a map held in memory, those it was described with, which given ones must equal (the frames
    are compared with its rows, and a results header records them)."""
    if not isinstance(map, Entry):
        return descriptor or "sad", params
    if descriptor is not None and descriptor != map.descriptor:
        raise ParameterError("descriptor", f"the map held in memory was described with {map.descriptor!r}, not "
                                           f"{descriptor!r}")
    own = entry_params(map)
    if params is not None and json.loads(json.dumps(descriptor_spec(map.descriptor, params).params,
                                                    sort_keys=True)) != own:
        raise ParameterError("descriptor_params", f"the map held in memory was described with {own!r}, "
                                                  f"not {dict(params)!r}")
    return map.descriptor, own


class RunSession:
    """A run against ``map`` (a traversal, a descriptor matrix file or an ``Entry`` in memory;
    None: sequence mode, loop closure within the query's own frames).

    A batch run gives its ``query`` (described first, then the map) with its odometry
    (``odometry``: a CSV; ``odometry_topic``: the topic of the query's and the map's ROS bags);
    a streaming run gives none and computes each frame's row with :meth:`row`. ``exclude_recent``
    (R) None means not given: :data:`DEFAULT_EXCLUDE_RECENT`; given against a map to a method that
    does not learn from the map's differences to itself, where it changes nothing, it is a
    ParameterError (as the CLI refuses ``--exclude-recent`` there). ``restoring``
    leaves the method's inputs unchecked: a saved state is continued, which was checked when it
    was started. ``progress``, ``scheduler`` and ``topic`` are the batch run's describing;
    ``map_topic`` (None: ``topic``) is the image topic of a map ROS bag recorded with another topic's
    name than the query's, refused for any other map.
    """

    def __init__(self, map: str | os.PathLike | Entry | None, *, method: str,
                 method_params: Mapping[str, Any] | None = None,
                 descriptor: str | None = "sad", descriptor_params: Mapping[str, Any] | None = None,
                 metric: str | None = None, exclude_recent: int | None = None,
                 training: TrainingPair | None = None, map_odometry: str | os.PathLike | None = None,
                 map_names: str | os.PathLike | None = None, query: Path | None = None,
                 query_names: Path | None = None, odometry: str | os.PathLike | None = None,
                 odometry_topic: str | None = None,
                 sampling: Sampling | None = None, cache: Cache | str | os.PathLike | None = None, jobs: int | None = None,
                 progress: Progress | None = None, scheduler: str | None = None, topic: str | None = None,
                 map_topic: str | None = None, restoring: bool = False) -> None:
        if training is not None and not isinstance(training, (Training, TrainingRows)):
            raise ParameterError("training", "a labelled pair: Training(query, reference, truth) (wiloc.api.Training) "
                                             f"or TrainingRows(rows, labels), got {type(training).__name__}")
        for name, path in (("odometry", odometry), ("map_odometry", map_odometry), ("map_names", map_names)):
            if path is not None:
                check_traversal(path, name, " or None", what="a file's path (text or a path object)")
        self.method: Method = make_method(method, method_params)
        self.exclude_recent = R = DEFAULT_EXCLUDE_RECENT if exclude_recent is None else check_exclude_recent(exclude_recent)
        if exclude_recent is not None and map is not None and not restoring and "map_self" not in self.method.needs:
            raise ParameterError("exclude_recent", f"has no effect against a map for method '{self.method.name}': it "
                                                   f"applies to sequence mode (no map), and against a map to the methods "
                                                   f"that learn from the map's differences to itself "
                                                   f"({', '.join(learning_from_the_map())})")
        self.sequence = map is None
        self.map_path = None if map is None or isinstance(map, Entry) else Path(map)
        self.map_odometry = None if map_odometry is None else Path(map_odometry)
        self.map_names = None if map_names is None else Path(map_names)
        self.odometry = None if odometry is None else Path(odometry)
        self.odometry_topic = odometry_topic
        self.training = training
        self.query_path = None if query is None else Path(query)
        self._query_bag, self._map_bag = bag_odometry(query, self.map_path, odometry_topic, odometry, map_odometry)
        if not restoring:
            self._check_inputs(training is not None, odometry is not None, map_odometry is not None,
                               tuple(method_params or {}))
        sources = [Path(source) for source in (query, map) if source is not None and not isinstance(source, Entry)]
        check_sampling(sources, sampling)
        check_metric(sources, metric)  # a map held in memory is no source: no metric to check against it
        if not restoring:  # a saved state records the describer's descriptor, even over matrix files
            check_descriptor(sources, descriptor, descriptor_params)
        pair = (training.query, training.reference) if isinstance(training, Training) else ()
        if map_topic is not None and (self.map_path is None or not is_bag(self.map_path)):
            raise ParameterError("map_topic", "applies to a ROS bag map only; "
                                              f"{'sequence mode has no map' if map is None else f'{map} is not one'}")
        self.map_topic = map_topic
        topic_read = (query, *pair) if map_topic is not None else (query, map, *pair)  # the traversals --topic reads
        check_topic([Path(s) for s in topic_read if s is not None and not isinstance(s, Entry)], topic)
        descriptor, descriptor_params = _map_descriptor(map, descriptor, descriptor_params)
        self.describer = Describer(descriptor, parameter_values(descriptor_params, "descriptor_params"),
                                   Cache.given(cache), metric=metric, jobs=jobs, progress=progress, sampling=sampling,
                                   cluster=open_cluster(scheduler, jobs), topic=topic)
        before = len(self.describer.skipped)
        self.query: Entry | None = None if query is None else self.describer.entry(Path(query), query_names)
        self._query_skipped = [Path(path).name for path, _ in self.describer.skipped[before:]]  # the query's own
        self.map: Entry | None = None
        self.map_left_out: tuple[tuple[int, str], ...] | None = None  # the map's frames left out: (position, name)
        if map is not None:
            # a copy reading the map's topic, which adds its skipped frames and notes to the same lists
            map_describer = self.describer if map_topic is None else replace(self.describer, topic=map_topic)
            before = len(self.describer.skipped)
            self.map = map if isinstance(map, Entry) else map_describer.entry(Path(map), map_names)
            skipped = [Path(path).name for path, _ in self.describer.skipped[before:]]  # the map's own
            self.map_left_out = left_out(self.map.names, skipped)
            self._check_map(R)
        self.kind = self.method.row_kind(self.describer.descriptor)
        self.evidence = self.method.evidence(self.describer.spec) if self.kind == "log_ratio" else None
        self._count = 0  # sequence mode: the frames added as candidates so far
        candidates = self.map if self.map is not None else self.query  # a batch run's sequence mode: its query's
        if candidates is None:  # a streaming run's sequence mode: the frames it is given
            spec = self.describer.spec
            self._seen = np.empty((0, spec.length), dtype=spec.dtype)
            self.metric, self.scale, self.natural_max = spec.metric, spec.scale, spec.natural_max
        else:
            self._seen = candidates.data[:0]
            self.metric, self.scale, self.natural_max = candidates.metric, candidates.scale, candidates.natural_max
        if self.map is not None and self.evidence is not None:
            self.evidence.add_places(self.map.data)

    @classmethod
    def restored(cls, meta: Mapping[str, Any], map: Entry | None, cache: Cache | str | os.PathLike | None,
                 jobs: int | None) -> RunSession:
        """The session of a saved localizer's state (``Localizer.state``), its inputs unchecked
        (they were when it started); ``map`` is the map it held in memory, if it did."""
        saved_map = map if map is not None else None if meta["map"] is None else Path(meta["map"])
        map_names = meta.get("map_names")  # states saved before it was recorded: a map without a names file
        return cls(saved_map, method=meta["method"],
                   method_params={k: tuple(v) if isinstance(v, list) else v for k, v in meta["params"].items()},
                   descriptor=meta["descriptor"], descriptor_params=meta["descriptor_params"], metric=meta["metric"],
                   exclude_recent=meta["exclude_recent"],
                   map_odometry=None if meta["map_odometry"] is None else Path(meta["map_odometry"]),
                   map_names=None if map_names is None else Path(map_names),
                   sampling=None if meta["sampling"] is None else Sampling(**meta["sampling"]),
                   topic=meta.get("topic"), cache=cache, jobs=jobs, restoring=True,
                   training=None if meta.get("training") is None else Training.restored(meta["training"]))

    @cached_property
    def map_rows_digest(self) -> str | None:
        """``descriptors_digest`` of the map's frames (None in sequence mode), computed once: what a
        results header records of the map, and what a saved state knows a copy of it by."""
        return None if self.map is None else descriptors_digest(self.map.names, self.map.data)

    def map_odometry_digest(self) -> str | None:
        """SHA-256 of the map's odometry CSV as it is now (None without one): a saved localizer's
        state keeps it, so that a CSV rewritten since is refused on loading, as a changed map is."""
        if self.map_odometry is None:
            return None
        read_odometry(self.map_odometry)  # a missing or malformed CSV refused as the run refuses it
        return hashlib.sha256(self.map_odometry.read_bytes()).hexdigest()

    def changed_settings(self) -> dict[str, Any]:
        """The setup that differs from the defaults, as a ``Localizer`` shows it (two that decide
        otherwise show otherwise; the method shows its parameters): the descriptor's parameters
        other than its defaults (all given, for a descriptor without defaults: ``bow``'s file;
        none for imported rows, which no descriptor computes), exclude_recent, and the map's
        odometry and names files, sampling and topics."""
        spec, describer = self.describer.spec, self.describer
        try:
            defaults = descriptor_spec(spec.name).params
        except WilocError:  # a descriptor with a required parameter
            defaults = {}
        imported = spec.kind.imported or self.map_path is not None and is_matrix_file(self.map_path)
        params = {} if imported else {k: v for k, v in spec.params.items() if k not in defaults or defaults[k] != v}
        shown = {"descriptor_params": params or None,
                 "exclude_recent": None if self.exclude_recent == DEFAULT_EXCLUDE_RECENT else self.exclude_recent,
                 "map_odometry": None if self.map_odometry is None else str(self.map_odometry),
                 "map_names": None if self.map_names is None else str(self.map_names),
                 "sampling": None if describer.sampling == Sampling() else describer.sampling,
                 "topic": describer.topic, "map_topic": self.map_topic}
        return {name: value for name, value in shown.items() if value is not None}

    def training_state(self) -> dict[str, Any] | None:
        """The training pair as a saved localizer's state keeps it (``Training.state``), so that
        a loaded one's results header records it; None without one, or for rows given as arrays
        (the header records no pair for them)."""
        return self.training.state() if isinstance(self.training, Training) else None

    @cached_property
    def _to_map(self) -> DifferencesTo:
        """The map prepared for frame-by-frame differences (a streaming run's; made on first use)."""
        return DifferencesTo(self.map.data, self.metric, self.scale)

    def _check_inputs(self, training: bool, odometry: bool, map_odometry: bool, given: tuple[str, ...]) -> None:
        """The method's refusal of an input it does not take, naming the input as given: an
        odometry read from a ROS bag is ``odometry_topic``'s, not a CSV's; a query bag's topic against
        a map that is no bag is told the map's must come as a CSV. A run over a query
        traversal given the map's odometry CSV and not the query's would not use it: refused, not
        ignored (a Localizer is given the query's odometry frame by frame)."""
        try:
            if self.query_path is not None:
                given_odometry: bool | None = odometry or self._query_bag
            else:  # a Localizer's comes frame by frame, against a map only with the map's
                given_odometry = None if self.sequence or map_odometry or self._map_bag else False
            self.method.check_inputs(sequence=self.sequence, training=training, odometry=given_odometry,
                                     map_odometry=map_odometry or self._map_bag, given=given)
        except WilocError as exc:
            from_bag = {"odometry": self._query_bag, "map_odometry": self._map_bag}  # never besides a CSV
            if exc.parameter == "reference" and self.query_path is None:  # a Localizer's is its map
                raise UsageError(None, exc.problem, parameter="map") from None
            if exc.parameter == "map_odometry" and self._query_bag and not (map_odometry or self._map_bag):
                named = "" if self.map_path is None else f" {self.map_path}"
                raise UsageError(None, f"the map{named} is not a ROS bag: it has no odometry topic; give its "
                                       "odometry as a CSV, in the units of the query's",
                                 parameter="map_odometry") from None
            if not from_bag.get(exc.parameter or ""):
                raise
            raise UsageError(None, exc.problem, parameter="odometry_topic") from None
        if map_odometry and self.query_path is not None and not (odometry or self._query_bag):
            raise UsageError(None, "the map's odometry is used only with the query's; give the query's odometry "
                                   "too, or neither", parameter="map_odometry")

    def _check_map(self, R: int) -> None:
        """One place for the map's size checks: two frames at least, and for methods learning
        from the map's differences to itself, two frames further apart than the recent window."""
        n_map, where = len(self.map.names), self.map_path if self.map_path is not None else self.map.folder
        if n_map < 2:
            raise WilocError(where, f"the map has {n_map} frame(s); it needs at least 2")
        if "map_self" in self.method.needs and n_map <= R + 1:
            raise WilocError(where, f"the map has {n_map} frames: with exclude_recent={R} no two map "
                                    "frames are far enough apart to learn different-place differences")

    def recorded(self) -> dict[str, Any]:
        """What a results header records of this run's inputs besides its setup
        (``wiloc.localization.run_files.run_header``): the digests of the query's descriptors (a
        batch run's; a streaming run keeps none) and the map's ("" in sequence mode), a video's or
        bag's sampling and topics (the map's apart when it has its own), FAB-MAP's evidence rows
        with the folders they were trained on, and the map's frames left out (unreadable), which
        ground truth counting the map's frames in order counts too."""
        streamed = any(path is not None and is_stream(path) for path in (self.query_path, self.map_path))
        q, evidence = self.query, self.evidence
        return {"query_digest": None if q is None else descriptors_digest(q.names, q.data),
                "map_digest": self.map_rows_digest or "",
                "sampling": asdict(self.describer.sampling or Sampling()) if streamed else None,
                "topic": self.describer.topic, "map_topic": self.map_topic, "odometry_topic": self.odometry_topic,
                "rows": "fabmap" if evidence is not None else None,
                "fabmap_training": tuple(evidence.training_folders) if evidence is not None else None,
                "reference_left_out": self.map_left_out}

    # ------------------------------------------------------------------------------------ context

    def context(self, differences: RunDifferences | None = None) -> MapContext:
        """What the method is started on: the map, read lazily and never stored whole. A batch
        run gives its ``differences`` (the summary of the map's differences to itself, in sequence
        mode of the query's, from the cache); a streaming run sweeps the map's when asked."""
        training = self._training_rows if self.training is not None else None
        if self.map is None:
            return MapContext(sequence=True, exclude_recent=self.exclude_recent, rows=self.kind,
                              natural_max=self.natural_max, arclength=self.map_arclength(),
                              map_summary=None if differences is None else differences.map_summary, training=training)
        data, metric, scale, R = self.map.data, self.metric, self.scale, self.exclude_recent
        return MapContext(
            sequence=False, exclude_recent=R, n_map=len(self.map.names), rows=self.kind,
            natural_max=self.natural_max, arclength=self.map_arclength(), frame_positions=self._map_positions(),
            map_summary=differences.map_summary if differences is not None
            else lambda: summarize(ComputedDifferences(data, self._to_map), R),
            neighbours=lambda: consecutive(data, metric, scale), training=training)

    def _map_positions(self) -> NDArray[np.float64] | None:
        """Each map frame's position in the map's full order, when frames of it were left out."""
        if self.map is None or self.map_left_out is None:
            return None
        gone = [position for position, _ in self.map_left_out]
        return np.delete(np.arange(len(self.map.names) + len(gone), dtype=np.float64), gone)

    def map_arclength(self) -> NDArray[np.float64] | None:
        """The map's arc length per frame (in a batch run's sequence mode, the query's), from its
        odometry CSV or its bag's topic; None without either."""
        candidates = self.map if self.map is not None else self.query
        if candidates is None:
            return None
        return traversal_arclength(candidates.names, self.map_odometry, self.map_path if self._map_bag else None,
                                   self.odometry_topic)

    def query_passed(self) -> NDArray[np.intp] | None:
        """A batch query's frames left out (unreadable) just before each kept frame (``Method.run``'s
        ``passed``), so that a step across them covers them; None when none was left out."""
        gone = left_out(self.query.names, self._query_skipped)
        if gone is None:
            return None
        positions = np.delete(np.arange(len(self.query.names) + len(gone)), [position for position, _ in gone])
        return np.diff(positions, prepend=-1) - 1

    def query_steps(self) -> NDArray[np.float64] | None:
        """A batch query's travelled distance per frame, from its odometry CSV or its bag's topic."""
        query_bag = self.query_path if self._query_bag else None
        return traversal_steps(self.query.names, self.odometry, query_bag, self.odometry_topic)

    def _training_rows(self) -> TrainingRows:
        """The labelled pair of ``trained``: given as rows, or computed from its traversals."""
        if isinstance(self.training, TrainingRows):
            return self.training
        return training_rows(self.training, self.describer, self.exclude_recent)

    # --------------------------------------------------------------------------------------- rows

    def batch_rows(self) -> Iterator[NDArray]:
        """Check the batch query, start the method on its run's context and give the rows that
        ``method.run`` decides: the query's difference rows read from the cache block by block,
        or FAB-MAP's evidence rows frame by frame (:meth:`row`)."""
        q = self.query
        problem = self.method.query_problem(len(q.names), self.sequence, self.exclude_recent)
        if problem is not None:
            raise WilocError(self.query_path, problem)
        source = run_differences(q, q if self.map is None else self.map, self.describer.cache, self.exclude_recent,
                                 self.describer.runner, progress=stage(self.describer.progress, "map differences"))
        self.method.start(self.context(source))
        if self.evidence is None:
            return candidate_blocks(source.rows, self.sequence, self.exclude_recent)
        return self._evidence_rows(q.data)

    def _evidence_rows(self, query: NDArray) -> Iterator[NDArray[np.float64]]:
        """The batch query's evidence rows, each frame added as a candidate once decided."""
        for packed in query:
            yield self.row(packed)
            self.add(packed)

    def row(self, descriptor: NDArray) -> NDArray[np.float64]:
        """The next frame's row: its differences to every map frame, or in sequence mode to every
        frame added so far (inf within the recent window); FAB-MAP's evidence for methods reading
        it (-inf for no candidate)."""
        k = self._count
        far = max(0, k - self.exclude_recent)
        if self.evidence is not None:
            if self.map is not None:
                return self.evidence.row(descriptor)
            row = np.full(k, -np.inf)
            if far:
                row[:far] = self.evidence.row(descriptor)[:far]
            return row
        if self.map is not None:
            return self._to_map(np.asarray(descriptor)[None, :])[0].astype(np.float64)
        row = np.full(k, np.inf)
        if far:
            row[:far] = pairwise(np.asarray(descriptor)[None, :], self._seen[:far], self.metric, self.scale)[0]
        return mask_recent(row, k, self.exclude_recent)

    def add(self, descriptor: NDArray) -> None:
        """A decided frame joins the candidates of later frames (sequence mode; against a map,
        the candidates are the map's)."""
        if self.map is not None:
            return
        k = self._count
        if k == self._seen.shape[0]:
            grown = np.empty((max(16, 2 * k), self._seen.shape[1]), dtype=self._seen.dtype)
            grown[:k] = self._seen
            self._seen = grown
        self._seen[k] = descriptor
        self._count = k + 1
        if self.evidence is not None:
            self.evidence.add_places(descriptor)

    def resume(self, seen: NDArray) -> None:
        """Sequence mode: the candidates of a saved run, added again (as :meth:`add` did)."""
        self._seen = np.asarray(seen).astype(self._seen.dtype, copy=True)
        self._count = len(self._seen)
        if self.evidence is not None and self._count:
            self.evidence.add_places(self._seen)

    @property
    def seen(self) -> NDArray:
        """The descriptors of the frames added as candidates (sequence mode), in order."""
        return self._seen[:self._count]

    def made_up_rows(self, start: int) -> Iterator[NDArray[np.float64]]:
        """Sequence mode: endless rows of made-up frames, as :meth:`row` would give the frames
        after the first ``start`` (inf within the recent window; FAB-MAP's rows -inf there), their
        values the run's own difference kernel's between random descriptors of the candidates'
        length and type. A copy of the method stepped over them builds its compiled kernels
        before a real frame needs them; the session itself is left as it was."""
        rng, seen = np.random.default_rng(0), self._seen
        if seen.dtype.kind in "iu":
            made = rng.integers(0, min(256, np.iinfo(seen.dtype).max + 1), (32, seen.shape[1])).astype(seen.dtype)
        else:
            made = rng.random((32, seen.shape[1])).astype(seen.dtype)
        values = pairwise(made, made, self.metric, self.scale).astype(np.float64)
        sign, blank = (-1.0, -np.inf) if self.kind == "log_ratio" else (1.0, np.inf)
        for k in itertools.count(start):
            row = np.full(k, blank)
            far = max(0, k - self.exclude_recent)
            row[:far] = sign * np.resize(values[k % len(made)], far)
            yield row

    @property
    def candidates_data(self) -> NDArray:
        """The candidates' descriptors: the map's, or in sequence mode the frames added."""
        return self.map.data if self.map is not None else self._seen

    def doubts(self) -> list[str]:
        """What makes every result of this run doubtful, one line each: its odometry CSVs' (distances
        that read as from the start), its descriptor's (bow: a sparse vocabulary), then its query's
        (a batch run's) and its map's descriptors' (bow: images that give too few words), each
        naming its folder; no descriptor's for a run on imported descriptors (a query or map that
        is a descriptor matrix file): the descriptor did not make them."""
        odometry = [doubt for csv in (self.odometry, self.map_odometry) if csv is not None
                    and (doubt := read_odometry(csv).doubt()) is not None]
        if any(path is not None and is_matrix_file(path) for path in (self.query_path, self.map_path)):
            return odometry
        kind, params = self.describer.spec.kind, self.describer.spec.params
        return odometry + kind.doubts(params) + [
            f"{role} {entry.folder}: {line}" for role, entry in (("query", self.query), ("map", self.map))
            if entry is not None for line in kind.traversal_doubts(entry.data, params)] + shape_doubts(self.query, self.map)


#: Query and map frames whose width / height ratios differ by more than this share are warned of.
ASPECT_TOLERANCE = 0.1


def shape_doubts(query: Entry | None, reference: Entry | None) -> list[str]:
    """A line for each size of the query's frames whose shape is not the map's
    (:func:`shape_doubt`), counting its frames when others are of other sizes."""
    if query is None or reference is None or query.frame_size is None:
        return []
    total = sum(count for _, count in query.frame_sizes) or 1
    lines = (shape_doubt(size, reference.frame_size, "frames" if count == total else f"{count} of {total} frames")
             for size, count in query.frame_sizes or ((query.frame_size, total),))
    return [f"query {query.folder}: {line}" for line in lines if line is not None]


def shape_doubt(size: tuple[int, int], map_size: tuple[int, int] | None, frames: str = "frames") -> str | None:
    """Why ``frames`` of ``size`` (width, height) are doubtful against a map of frames of
    ``map_size``, when the shapes differ (another camera, or a crop of one side): a whole-image
    descriptor squeezes each frame to one fixed size, which can make the same place look
    otherwise in each. Sizes alone (the same shape) are no doubt; None then, or without a size."""
    if map_size is None:
        return None
    (qw, qh), (rw, rh) = size, map_size
    if abs(np.log((qw / qh) / (rw / rh))) <= np.log1p(ASPECT_TOLERANCE):
        return None
    return (f"{frames} of {qw} x {qh} pixels against the map's {rw} x {rh}, another shape: a whole-image "
            "descriptor squeezes both to one size, which can make the same place look otherwise (if one is "
            "a crop of the other, crop the other alike)")
