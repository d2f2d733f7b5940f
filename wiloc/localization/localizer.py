"""The streaming localizer: one frame in (an image, an image file or a descriptor), a decision out.

``Localizer`` describes each frame, takes its row from its run session (``wiloc.localization.session``, shared
with the batch ``wiloc.api.localize``): its differences to the map (or, in sequence mode, to every
earlier frame outside the recent window: the map grows as frames arrive), and steps the chosen
method. Per-frame cost is bounded by the map's size: no N x N matrix is built; the map's
differences to itself, which some methods learn from when started, are computed block by block
and never stored. The decisions made are kept, compactly, so that ``results`` gives the run's
results as a batch run of the same frames does. ``save``/``load`` let a long run stop and resume
with identical decisions, and keep the decisions made before.
"""
from __future__ import annotations

import copy
import os
from collections.abc import Mapping
from dataclasses import asdict, replace
from itertools import chain, count
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc import __version__
from wiloc.cache.store import Cache, Entry
from wiloc.decisions import Decision
from wiloc.description.traversals import Describer, checked_rows, descriptor_label, is_matrix_file, names_matrix_file
from wiloc.errors import ParameterError, WilocError, shown_name
from wiloc.evaluation.results import Results
from wiloc.evaluation.results_header import ResultsHeader
from wiloc.interrupts import interrupts_deferred
from wiloc.localization.frame_arrays import check_query, colour_image, file_image, frame_array, frame_path, gray_image
from wiloc.localization.session import RunSession, TrainingPair, check_traversal, shape_doubt
from wiloc.localization.state_file import read_state, state_parts, state_whole, write_state
from wiloc.localization.streamed import DecisionLog, streamed_header, streamed_results
from wiloc.sources.video import Sampling

STATE_FORMAT = "wiloc-localizer-state"
#: 8: a digest of the contents, checked on loading; 7: catgraph's unexplained stretch keeps the track's
#: pace; 6: the decisions made are kept (``results``); 5: catgraph reads each node against its chance
#: resemblance; 4: sequence mode runs the catgraph filter; 3: catgraph knows a repeated image; 2: it
#: ranks FAB-MAP evidence
STATE_VERSION = 8

#: Sequence mode: the made-up frames a copy of the method steps, at most, to build its compiled
#: kernels (:meth:`Localizer._compile`), and how many it steps after its first whole decision.
TRIAL_FRAMES = 400
SETTLED_FRAMES = 2


class Localizer:
    """Frame-by-frame localization against a map (or within the run itself, in sequence mode).

    ``map`` is one traversal (a folder, video or ROS bag), a descriptor matrix file (with ``metric``) or an
    in-memory ``Entry`` (descriptors in an array: ``wiloc.description.traversals.entry_from_array``), None for
    sequence mode (loop closure within the frames observed); anything else is a ParameterError naming
    ``map``. ``descriptor`` and ``descriptor_params`` describe the frames (default ``sad``; a map
    held in memory brings its own, which given ones must equal). ``method`` names a registered method and
    ``params`` its parameters; ``training`` is the labelled pair of ``trained`` (traversals, or
    their difference rows and truth as ``TrainingRows``); ``sampling`` the frames of a map video; ``topic`` the
    image topic of a map ROS bag (needed when it has several); ``map_odometry``
    the map's odometry CSV for methods that take odometry.

    It keeps every decision it makes (about 60 bytes a frame, and 8 per ranked candidate: 220 for
    the methods that rank), so that :meth:`results` gives the run's results, scored by
    ``wiloc.evaluate`` and written by ``Results.save`` as a batch run's; :meth:`save`, :meth:`load`
    and pickling keep them.

        loc = Localizer(map="day_right/", descriptor="sad", method="catgraph", seed=0)
        for path in api.frames("day_left"):   # (from wiloc import api) in the order a batch run reads them
            decision = loc.observe(path)
        loc.results(query="day_left/").save("day_left-sad-catgraph.csv")   # wiloc evaluate reads it
    """

    def __init__(self, map: str | Path | Entry | None = None, *, descriptor: str | None = None,
                 descriptor_params: Mapping[str, Any] | None = None, metric: str | None = None,
                 method: str = "online", exclude_recent: int | None = None,
                 training: TrainingPair | None = None, map_odometry: str | Path | None = None,
                 map_names: str | Path | None = None, sampling: Sampling | None = None, topic: str | None = None,
                 cache: Cache | str | os.PathLike | None = None, jobs: int | None = None, **params: Any) -> None:
        _check_unused(_map(map), metric, map_odometry, map_names)
        self._setup(RunSession(map, method=method, method_params=params, descriptor=descriptor,
                               descriptor_params=descriptor_params, metric=metric, exclude_recent=exclude_recent,
                               training=training, map_odometry=map_odometry, map_names=map_names, sampling=sampling,
                               topic=topic, cache=cache, jobs=jobs))
        self.method.start(self._session.context())
        self._compile()

    def _compile(self) -> None:
        """Step a copy of the method so that its compiled kernels are built (or loaded from the
        cache) as the localizer starts or is loaded, not on a frame a robot gives it: catgraph's
        first frames took 7 s of CPU on a machine that had not built them yet. Against a map the
        copy steps over three map frames (with a step of odometry where the run's frames must have
        one); in sequence mode, where the filter starts only once the
        run has frames enough (frame 72 with catgraph's defaults), over made-up frames
        (:meth:`RunSession.made_up_rows`, each with a step of odometry where the run's frames must
        have one: ``Method.odometry_next``) until it decides with every value it gives, then
        :data:`SETTLED_FRAMES` more (at most :data:`TRIAL_FRAMES` in all). The copy is dropped:
        the localizer's own state, its random generator's too, is untouched, so its decisions do
        not change."""
        trial, reference = copy.deepcopy(self.method), self._session.map
        if reference is not None:
            for descriptor in reference.data[:3]:
                trial.step(self.row(descriptor), 1.0 if trial.odometry_next() else None)
            return
        settled = 0
        for _, row in zip(range(TRIAL_FRAMES), self._session.made_up_rows(trial.frames)):
            decision = trial.step(row, 1.0 if trial.odometry_next() else None)
            whole = np.isfinite(decision.confidence) and ("new_place" not in trial.columns
                                                          or np.isfinite(decision.new_place))
            settled += bool(whole or settled)
            if settled > SETTLED_FRAMES:
                return

    def _setup(self, session: RunSession) -> None:
        """Everything but the method's start: shared by a new localizer and a loaded one."""
        self._session = session
        self.method = session.method
        self.exclude_recent = session.exclude_recent
        self.sequence = session.sequence
        self.names: list[str] = []  # the frames observed, in order
        self._named: set[str] = set()  # the same, looked up for each new name
        self._log = DecisionLog(self.method.columns, self.method.ranks)  # their decisions
        self.frame_doubts: list[str] = []  # one line per shape of the images described that is not the map's
        self._shapes: set[tuple[int, int]] = set()  # the (width, height) of the images described
        path, spec = session.map_path, session.describer.spec
        imported = path is not None and is_matrix_file(path) or spec.kind.imported  # a file's, or rows in memory
        self._spec = None if imported else spec
        self._odometry_digest = session.map_odometry_digest()  # the CSV the method reads as it starts

    @property
    def doubts(self) -> list[str]:
        """What makes every decision doubtful (``RunSession.doubts``: bow's sparse vocabulary, a
        map whose images give too few words; none for a map of imported descriptors), then what
        makes the frames observed so far doubtful (:attr:`frame_doubts`)."""
        return self._session.doubts() + self.frame_doubts

    @property
    def describer(self) -> Describer:
        """How frames are described: the descriptor, its parameters and the cache."""
        return self._session.describer

    @property
    def metric(self) -> str:
        """The difference the frames are compared with."""
        return self._session.metric

    @property
    def map_names(self) -> list[str]:
        """The candidate frames' names: the map's, or in sequence mode the frames observed."""
        return self.names if self._session.map is None else self._session.map.names

    def read(self, path: str | Path) -> NDArray[np.uint8]:
        """The 8-bit gray image that an image file's descriptor is computed from, in the map's
        cache as in :meth:`observe`: a JPEG decoded in reduced size where the descriptor allows
        it, gray from the decoder (for a colour descriptor, ``onnx``: BGR, in full).
        ``observe(loc.read(path))`` decides as ``observe(path)``."""
        if self._spec is None:
            raise WilocError(path, "a map of imported descriptors takes descriptors, not images")
        path = frame_path(path) or Path(path)  # an empty path, bytes no path can be: refused as observe refuses them
        return file_image(path, self._spec.colour, self._spec.min_size)

    def describe(self, frame: NDArray | str | bytes | os.PathLike) -> NDArray:
        """The descriptor of an image file (any path, bytes too), a decoded image
        (``frame_arrays.gray_image``) or a descriptor given as it is (:meth:`_descriptor`): a row, or a
        1 x D array of the map's length D. A k x D array that is no image this map takes is told as
        k descriptor rows, where the image's checks said it was too narrow (2 x D)."""
        if (path := frame_path(frame)) is not None:
            frame = self.read(path)
        array = frame_array(frame)
        length = self._session.candidates_data.shape[1]
        if array.ndim == 2 and array.shape == (1, length):
            array = array[0]  # one descriptor as a batch of one (a network's output, rows[k:k + 1])
        if array.ndim == 1:
            return self._descriptor(array)
        rows = path is None and array.ndim == 2 and array.shape[1] == length  # k descriptors, maybe
        try:
            if self._spec is None:
                raise WilocError("observe", "a map of imported descriptors takes descriptors, not images")
            image = colour_image(array) if self._spec.colour else gray_image(array)
        except WilocError:
            if not rows:
                raise
            raise WilocError("observe", f"an array of {array.shape[0]} x {length} looks like {array.shape[0]} "
                                        f"descriptor rows; observe takes one frame at a time: a row of {length} "
                                        f"values (or 1 x {length})") from None
        self._check_shape(image, decoded=path is not None)
        return self._spec.compute(image)

    def _check_shape(self, image: NDArray, decoded: bool) -> None:
        """A line in :attr:`frame_doubts` for the first image of each shape other than the map's
        (``shape_doubt``, as a batch run warns); a JPEG file may be decoded at 1/2 to 1/8 size."""
        size = (image.shape[1], image.shape[0])
        if size not in self._shapes and self._session.map is not None:
            self._shapes.add(size)
            if line := shape_doubt(size, self._session.map.frame_size, "images decoded" if decoded else "images"):
                self.frame_doubts.append(f"observe: {line}")

    def _descriptor(self, row: NDArray) -> NDArray:
        """A descriptor row given to :meth:`observe`, in the map's dtype: as long as the map's
        rows, finite, whole numbers in range for a map of integer rows (``sad``, ``brisk-gist``),
        and small enough that its differences do not overflow (``checked_rows``)."""
        data = self._session.candidates_data
        length, dtype = data.shape[1], data.dtype
        if row.size != length:
            held = "this map's" if self._session.map is not None else "this run's earlier frames'"  # sequence mode
            raise WilocError("observe", f"a descriptor of {row.size} values; {held} have {length}")
        return checked_rows(row, dtype, self._session.metric, "observe")

    def row(self, descriptor: NDArray) -> NDArray[np.float64]:
        """The next frame's row (:meth:`RunSession.row`): its differences to every map frame, or
        in sequence mode to every observed frame; FAB-MAP's evidence for methods reading it."""
        return self._session.row(descriptor)

    def observe(self, frame: NDArray | str | bytes | os.PathLike, name: str | None = None,
                odometry: float | None = None) -> Decision:
        """Decide one frame: describe it, compare it, step the method. ``frame`` is an image file's
        path, an image array or a descriptor row (:meth:`describe`). ``name`` defaults to the file's
        name, else the frame's index (zero-padded); ``odometry`` is the distance travelled since the
        previous frame, for methods that take it. Ctrl-C during the step is held until the frame
        is recorded: the frame is decided whole or not at all."""
        name = self._new_name(frame, name)
        descriptor = self.describe(frame)
        row = self.row(descriptor)
        with interrupts_deferred():  # a Ctrl-C (the guide's camera loop) leaves the frame whole, or not begun
            decision = self.method.step(row, odometry)
            self._session.add(descriptor)
            self._log.append(decision)
            self.names.append(name)
            self._named.add(name)
        candidates = self.map_names
        match_name = candidates[decision.match] if decision.match >= 0 else ""
        return replace(decision, frame=name, match_name=match_name)

    def skip(self, frames: int = 1) -> None:
        """The query passed ``frames`` frames (an image :meth:`observe` could not read): the next
        step covers them, as a batch run steps across the frames it leaves out (``Method.skip``)."""
        self.method.skip(frames)

    def _new_name(self, frame: object, name: object) -> str:
        """The next frame's name, checked before anything is decided: text, not empty, and no
        earlier frame's, since results hold one row per name (a file naming a frame twice is
        refused when read). Without a ``name``, a file's name, or the frame's index; one an earlier
        frame has (a camera that writes latest.jpg again and again, an index given as a name) gets
        a free name: a file's the index after its stem (``latest-000012.jpg``), then a count after
        that (``latest-000012-2.jpg``), an index's the count (``000012-2``)."""
        if name is None:  # a file's own name that is not UTF-8 is refused with the file, as a frame
            k = len(self.names)
            path = frame_path(frame)
            first = [f"{k:06d}"] if path is None else [path.name, f"{path.stem}-{k:06d}{path.suffix}"]
            stem, suffix = os.path.splitext(first[-1])
            name = next(n for n in chain(first, (f"{stem}-{j}{suffix}" for j in count(2))) if n not in self._named)
        elif isinstance(name, str) and shown_name(name) != name:  # as a batch run refuses such a file
            raise WilocError("observe", f"name '{shown_name(name)}' is not valid UTF-8 (results files hold names "
                                        "as UTF-8 text)")
        if not isinstance(name, str):
            raise WilocError("observe", f"name must be text (str), got {type(name).__name__} {name!r}")
        name = str(name)  # numpy's text (np.str_) as plain str, as results hold it
        if not name:
            raise WilocError("observe", "name is empty")
        if name in self._named:
            raise WilocError("observe", f"name '{name}' is an earlier frame's (frame {self.names.index(name)}); "
                                        "each frame needs a name of its own (name=...)")
        return name

    # ------------------------------------------------------------------------------------ results

    def results(self, query: str | os.PathLike | None = None) -> Results:
        """The run's results so far: one row per frame observed, in order, with the header, model
        and columns a batch ``wiloc.localize`` of the same frames gives (and, when decisions are
        the same, the same rows): ``wiloc.evaluate`` scores them, ``Results.save(path)`` writes
        the file ``wiloc evaluate`` and ``wiloc compare`` read. ``query`` is the traversal the
        frames came from (a folder), recorded as a batch run records its query: ground truth
        that finds its files by the query's name (``{query}``) or reads its images needs it.
        Against a map the query's digest is left out: no query descriptors are kept (in
        sequence mode they are the candidates, kept, and the digest is the batch run's)."""
        if query is not None:
            check_traversal(query, "query", " or None")
            check_query(Path(query), described=self._spec is not None)
        return streamed_results(self._session, self._log, self.names, query)

    def header(self, query: str | os.PathLike | None = None) -> ResultsHeader:
        """What the results file of this run starts with (a followed folder's as it starts, before
        any row): the setup and inputs, the method's parameters as they are now and the map's
        frames; no model, and no query digest (a followed folder's file gets what the run learned
        when it ends: ``wiloc.localization.follow_run.FollowRun``)."""
        return streamed_header(self._session, query)

    # -------------------------------------------------------------------------------- save / load

    def state(self) -> dict[str, Any]:
        """Everything needed to continue: the setup, the frames observed (and doubts) and the method's state."""
        session, describer = self._session, self._session.describer
        return {"format": STATE_FORMAT, "version": STATE_VERSION, "wiloc": __version__,
                "map": None if session.map_path is None else str(session.map_path.resolve()),
                "map_digest": None if session.map is None else session.map.digest,
                "map_rows": session.map_rows_digest,
                "map_odometry": None if session.map_odometry is None else str(session.map_odometry.resolve()),
                "map_odometry_digest": self._odometry_digest,
                "map_names": None if session.map_names is None else str(session.map_names.resolve()),
                "descriptor": describer.descriptor, "descriptor_params": dict(describer.params),
                "metric": describer.metric, "method": self.method.name,
                "sampling": None if describer.sampling is None else asdict(describer.sampling),
                "topic": describer.topic, "params": self.method.params.as_dict(), "exclude_recent": self.exclude_recent,
                "training": session.training_state(),
                "names": list(self.names), "seen": session.seen, "decisions": self._log.state(),
                "frame_doubts": list(self.frame_doubts), "shapes": sorted(self._shapes),
                "method_state": self.method.state()}

    def save(self, path: str | Path) -> Path:
        """Write :meth:`state` to ``path`` (an .npz file), atomically: a kill leaves the old file.
        Missing folders of ``path`` are created, as every file the library writes does; a write
        that fails (a full disk) is a WilocError naming the file."""
        check_traversal(path, "path", what="a file's path for the state (text or a path object)")
        write_state(Path(path), self.state())
        return Path(path)

    @classmethod
    def load(cls, path: str | Path, cache: Cache | str | os.PathLike | None = None, jobs: int | None = None,
             map: Entry | str | os.PathLike | None = None) -> Localizer:
        """A localizer continuing from a state written by :meth:`save`: its next decisions are the
        ones the saved localizer would have made. The map must be unchanged; a map that was held
        in memory is given again as ``map`` (a traversal's path given there is read instead of
        the one the state names, and must be the same map)."""
        check_traversal(path, "path", what="a saved state's file (text or a path object)")
        meta = read_state(Path(path), STATE_FORMAT, STATE_VERSION)
        return cls._continued(meta, Path(path), cache, jobs, map)

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        """Pickled (and copied) as :meth:`save` writes it, the map held in memory and the cache
        with it: the copy continues with the decisions this localizer would make, on its own."""
        meta, arrays = state_parts(self.state())
        in_memory = self._session.map if self._session.map_path is None else None
        return _unpickled, (meta, arrays, self.describer.cache, self.describer.jobs, in_memory)

    @classmethod
    def _continued(cls, meta: dict[str, Any], source: str | Path, cache: Cache | str | os.PathLike | None,
                   jobs: int | None, map: Entry | None) -> Localizer:
        """A localizer continuing from a :meth:`state` read back (``source``: where from, for errors)."""
        if map is not None and not isinstance(map, (Entry, str, os.PathLike)):
            raise ParameterError("map", f"the map the state was saved with, held in memory (an Entry) or its "
                                        f"traversal's path, or None, got {type(map).__name__}")
        if meta["map"] is None and meta["map_digest"] is not None and map is None:
            raise WilocError(source, "was saved with a map held in memory: give it again (map=...)")
        session = RunSession.restored(meta, map, cache, jobs)
        if session.map is not None and session.map.digest != meta["map_digest"] and (
                meta.get("map_rows") != session.map_rows_digest):  # a copy elsewhere has the same rows
            given = "" if map is None else f" (or the map given is not the one it was saved with: {meta['map']})"
            raise WilocError(session.map.folder, f"the map changed since {source} was saved{given}")
        loc = cls.__new__(cls)
        loc._setup(session)
        if meta.get("map_odometry_digest") not in (None, loc._odometry_digest):  # states saved before it was kept: none
            raise WilocError(session.map_odometry, f"the map's odometry changed since {source} was saved")
        loc.names = list(meta["names"])
        loc._named = set(loc.names)
        loc._log = DecisionLog.restored(loc.method.columns, loc.method.ranks, meta["decisions"])
        loc.frame_doubts = list(meta.get("frame_doubts", []))  # states saved before they were kept: none
        loc._shapes = {(width, height) for width, height in meta.get("shapes", [])}
        if session.map is None:
            session.resume(meta["seen"])
        loc.method.restore(session.context(), meta["method_state"])
        loc._compile()
        return loc

    @property
    def frames(self) -> int:
        """Frames observed so far."""
        return len(self.names)

    def __repr__(self) -> str:  # the descriptor as results name it: external:l1 for a map of imported descriptors
        where = "sequence mode" if self._session.map is None else f"map={self._session.map.folder!r}"
        label = descriptor_label(self.describer.descriptor, self.metric, [p for p in [self._session.map_path] if p])
        shown = "".join(f", {name}={value!r}" for name, value in self._session.changed_settings().items())
        return f"Localizer({where}, descriptor={label!r}{shown}, method={self.method!r}, frames={self.frames})"


def _unpickled(meta: str, arrays: dict[str, NDArray], cache: Cache, jobs: int | None, map: Entry | None) -> Localizer:
    """The localizer :meth:`Localizer.__reduce__` pickled."""
    return Localizer._continued(state_whole(meta, arrays), "the pickled localizer", cache, jobs, map)


def _map(map: object) -> str | os.PathLike | Entry | None:
    """``map`` checked before anything is described: one traversal's path, an ``Entry`` or None;
    anything else (a list of folders, an array of descriptors) is a ParameterError naming it."""
    if map is not None and not isinstance(map, Entry):
        check_traversal(map, "map", ", descriptors in memory as an Entry (wiloc.description.traversals."
                                    "entry_from_array(rows, names, spec)) or None for sequence mode")
    return map


def _check_unused(map: object, metric: object, map_odometry: object, map_names: object) -> None:
    """Refuse, as a ParameterError naming it, an option the map would not use, as the command line
    refuses its flag (``check_metric`` refuses a metric for a map of images, reading a matrix file
    an unknown one): a ``metric`` in sequence mode or other than a map held in memory's own;
    ``map_names`` but for a descriptor matrix file; ``map_odometry`` in sequence mode (each frame
    brings its own)."""
    if isinstance(map, Entry) and metric not in (None, map.metric):
        raise ParameterError("metric", f"the map held in memory is compared by '{map.metric}', not '{metric}'")
    if map is None and map_odometry is not None:
        raise ParameterError("map_odometry", "applies against a map only; in sequence mode each frame's odometry "
                                             "is given to observe (odometry=...)")
    matrix = isinstance(map, (str, os.PathLike)) and names_matrix_file(Path(map))
    for name, value in (("metric", metric if map is None else None), ("map_names", None if matrix else map_names)):
        if value is not None:
            none = "sequence mode has no map" if map is None else f"{map} is none" if not isinstance(map, Entry) \
                else "the map held in memory has its names"
            raise ParameterError(name, "applies to a map that is a descriptor matrix file (.npy, .npz, .csv, .h5) "
                                       f"only; {none}")
