"""What every localization method shares: its per-frame step, what it is started on, its output.

A method is a :class:`Method` subclass with its parameters declared as one frozen
:class:`~wiloc.parameters.Parameters` dataclass. It is started on a map (:class:`MapContext`, or
on nothing but the recent window in sequence mode) and then steps one query frame at a time: a
difference row (and, for methods that take it, an odometry step) in, one :class:`Decision` out.
Batch runs are that same step repeated (:meth:`Method.run`); ``wiloc.localization.localizer.Localizer`` feeds
it frame by frame. Adding a method is one module with a subclass and one line in
``wiloc/methods/registry.py``.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
from contextlib import closing
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from wiloc.ahead import computed_ahead
from wiloc.candidates import best_candidates
from wiloc.decisions import Decision, Decisions
from wiloc.errors import ParameterError, UsageError, WilocError, parameter_values
from wiloc.model import HistogramModel
from wiloc.parameters import Parameters, declared

if TYPE_CHECKING:
    from wiloc.descriptors.base import DescriptorSpec
    from wiloc.methods.fabmap_evidence import FabMapEvidence
    from wiloc.rows import MapSummary

Progress = Callable[[int, int], None]

AHEAD_ROWS = 64
"""Rows whose :meth:`Method.ahead` a batch run computes at once: enough that its helper thread
takes the GIL only a few times per 64 rows, few enough that what it keeps per row (an array or
two of the row's length) stays small."""

#: What a method can declare in ``needs``:
#: ``map``: it cannot run in sequence mode; ``map_self``: in map mode it learns from the map's
#: differences to itself outside +-R (so the map needs frames that far apart); ``map_neighbours``:
#: the difference of each map frame to the next; ``training``: a labelled training pair;
#: ``odometry``: it takes the query's travelled distance per frame.
NEEDS = ("map", "map_self", "map_neighbours", "training", "odometry")

#: What a query frame's row can hold: ``differences`` to each candidate (low: alike; inf: no
#: candidate) or FAB-MAP's ``log_ratio`` log p(Z | L_j) - log p(Z | new place) (high: alike;
#: -inf: no candidate), from bag-of-words descriptors (``wiloc.methods.fabmap_evidence``).
ROWS = ("differences", "log_ratio")


def self_summary(context: MapContext) -> MapSummary:
    """The summary of the map's differences to itself that the method was started on."""
    if context.map_summary is None:
        raise WilocError(None, "needs the map's differences to itself", parameter="reference")
    return context.map_summary()


@dataclass(frozen=True)
class TrainingRows:
    """A labelled training pair: its difference rows (an iterable read once) and its truth
    matrix (n_rows x n_candidates)."""

    rows: Iterable[NDArray[np.float64]]
    labels: Any  # dense bool array or scipy.sparse matrix


@dataclass(frozen=True)
class MapContext:
    """What a method is started on. Reading the map is lazy: a method reads only what it needs.

    ``map_summary`` gives what methods learn from the map's differences to itself (in sequence
    mode, when given, from the run's own matrix): each frame's minimum outside +-R, the largest;
    ``neighbours`` each map frame's difference to the next; ``training`` the labelled pair of
    ``trained``.
    """

    sequence: bool
    exclude_recent: int
    n_map: int = 0  # map frames (0 in sequence mode, where the candidates grow frame by frame)
    rows: str = "differences"  # what the rows hold: differences (low: alike) or log_ratio (high: alike)
    natural_max: float | None = None  # the descriptor's largest possible difference, if it has one
    arclength: NDArray[np.float64] | None = None  # map node positions along the route (odometry)
    #: each map frame's position in the map's full order when frames of it were left out (unreadable),
    #: so that a method placing nodes by frame number keeps the route's count across the gap
    frame_positions: NDArray[np.float64] | None = None
    map_summary: Callable[[], MapSummary] | None = None
    neighbours: Callable[[], NDArray[np.float64]] | None = None  # map frame j's difference to frame j + 1
    training: Callable[[], TrainingRows] | None = None


class Method(ABC):
    """A localization method: declared parameters, started on a map, stepped one frame at a time.

    Subclasses set ``name``, ``Params`` (a :class:`Parameters` dataclass), ``needs`` (a subset of
    :data:`NEEDS`), ``rows`` (the row kinds of :data:`ROWS` it reads) and ``columns`` (the
    per-frame extras written to results files), and implement
    :meth:`prepare`, :meth:`decide`, :meth:`save_state` and :meth:`load_state`. A method that
    ``ranks`` writes each decision's best candidates (Recall@N): those :meth:`decide` gives in
    ``Decision.ranking``, else the row's best (a method whose match is the row's best
    candidate); a method that cannot rank the map (SeqSLAM's trajectory end) sets it False.
    """

    name: ClassVar[str]
    Params: ClassVar[type[Parameters]]
    needs: ClassVar[frozenset[str]] = frozenset()
    rows: ClassVar[frozenset[str]] = frozenset({"differences"})  # the row kinds it reads (see ROWS)
    columns: ClassVar[tuple[str, ...]] = ()
    ranks: ClassVar[bool] = True  # decisions carry a ranking of the map (by default the row's best candidates)
    lowest_confidence: ClassVar[float] = 0.0  # confidences lie in [lowest_confidence, 1] (results files are checked)

    def __init__(self, params: Parameters | Mapping[str, Any] | None = None, **values: Any) -> None:
        if isinstance(params, Parameters):
            if values:
                raise TypeError("give parameters either as one Parameters object or as keywords")
            if not isinstance(params, self.Params):
                raise TypeError(f"{self.name} takes {self.Params.__name__}, got {type(params).__name__}")
            self.params = params
        else:
            self.params = self.Params.create({**parameter_values(params, "params"), **values})
        self.context: MapContext | None = None
        self.frames = 0  # query frames stepped since start
        self.passed = 0  # query frames passed since the last step without a row (left out: unreadable)

    def __repr__(self) -> str:
        changed = {k: v for k, v in self.params.as_dict().items()
                   if v != self.Params.create().as_dict().get(k)}
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in changed.items())})"

    def check_inputs(self, *, sequence: bool, training: bool, odometry: bool | None = False,
                     map_odometry: bool = False, given: Collection[str] = ()) -> None:
        """Refuse a run without what the method needs (``needs``), or with inputs it does not take
        (a query's odometry without the map's, which it is measured against; of the parameters
        ``given``, one that only sequence mode reads, against a map, and one that only the query's
        odometry is read with, without it). ``odometry`` None: it comes frame by frame, if at all
        (a Localizer's)."""
        for d in declared(self.Params):
            if d.name in given and d.sequence_only and not sequence:
                raise ParameterError(d.name, f"applies to sequence mode (no map) only: method '{self.name}' does "
                                             "not read it against a map")
            if d.name in given and d.odometry_only and odometry is False:
                raise ParameterError(d.name, f"applies to a run with the query's odometry only: method "
                                             f"'{self.name}' does not read it without")
        if "map" in self.needs and sequence:
            raise UsageError(None, f"method '{self.name}' needs a map (a reference trajectory)",
                             parameter="reference")
        if ("training" in self.needs) != training:
            problem = "needs a labelled training pair" if not training else "takes no training pair"
            raise UsageError(None, f"method '{self.name}' {problem}", parameter="training")
        for taken, parameter in ((odometry, "odometry"), (map_odometry, "map_odometry")):
            if taken and "odometry" not in self.needs:
                raise UsageError(None, f"method '{self.name}' takes no odometry", parameter=parameter)
        if odometry and not map_odometry and not sequence:  # refused before describing, not at the first frame
            raise UsageError(None, "the query's odometry needs the map's too, in the same units",
                             parameter="map_odometry")

    def row_kind(self, descriptor: str) -> str:
        """What this method's rows hold with this descriptor: FAB-MAP's evidence (``log_ratio``)
        for visual word presence (a descriptor whose class says ``words``, as ``bow``) when it
        reads that, else differences; a UsageError for a method that reads evidence only."""
        from wiloc.descriptors.registry import descriptor_class

        if descriptor_class(descriptor).words and "log_ratio" in self.rows:
            return "log_ratio"
        if "differences" not in self.rows:
            raise UsageError(None, f"method '{self.name}' reads FAB-MAP's evidence: give descriptor 'bow' "
                                   "with a vocabulary", parameter="descriptor")
        return "differences"

    def evidence(self, spec: DescriptorSpec) -> FabMapEvidence:
        """What makes this method's rows where they hold FAB-MAP's evidence (:meth:`row_kind`
        ``log_ratio``): the model of the vocabulary of ``spec``, with this method's parameters
        when they are FAB-MAP's."""
        from wiloc.methods.fabmap_evidence import FabMapEvidence  # scipy and the vocabulary load here

        return FabMapEvidence.of(spec, self.params)

    def query_problem(self, n_frames: int, sequence: bool, exclude_recent: int) -> str | None:
        """Why a query of ``n_frames`` frames cannot be run (in sequence mode or against a map,
        with this recent window), or None."""
        return None

    def start(self, context: MapContext) -> None:
        """Reset to the state before the first query frame, learning what it needs from the map."""
        self.context = context
        self.frames = 0
        self.passed = 0
        self.prepare(context)

    def skip(self, frames: int = 1) -> None:
        """The query passed ``frames`` frames that have no row (left out: an unreadable image):
        the next step covers them too (:attr:`elapsed`), as a map's frames left out keep their
        places (``MapContext.frame_positions``)."""
        if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
            raise ParameterError("frames", f"frames passed must be a whole number of at least 1, got {frames!r}")
        self.passed += int(frames)

    @property
    def elapsed(self) -> int:
        """Query frames from the previous step to the one being decided: 1, and more where frames
        were passed (:meth:`skip`). A method that moves a frame's step along the map reads it."""
        return 1 + self.passed

    def step(self, row: NDArray[np.floating], odometry: float | None = None, ahead: Any = None) -> Decision:
        """Decide one query frame from its difference row (and its travelled distance, for
        methods that take odometry); ``ahead`` is what :meth:`ahead` computed for this row, if
        the caller computed it (else the method does, when it needs it). A float32 row (as the
        difference kernels give them) is decided as it is, every other as float64: methods read
        its values as float64 either way, so the decisions are the same."""
        if self.context is None:
            raise RuntimeError(f"{self.name}: call start() before step()")
        if odometry is not None:
            if "odometry" not in self.needs:
                raise WilocError(self.name, f"method '{self.name}' takes no odometry", parameter="odometry")
            odometry = checked_step(odometry, self.frames)
            self.check_odometry()
        elif not self.context.sequence and self.odometry_next():  # sequence mode: the method says how
            raise WilocError(self.name, f"query frame {self.frames}: with the map's odometry, odometry comes with "
                                        "every frame after the first", parameter="odometry")
        row = as_row_dtype(np.asarray(row))
        if np.isnan(row).any():  # else argmin took the NaN for the best match, and catgraph refused it
            raise WilocError(self.name, f"query frame {self.frames}: the difference row holds NaN", parameter="row")
        self._ahead = ahead
        try:
            decision = self.decide(row, odometry)
        finally:
            self._ahead = None
        self.frames += 1
        self.passed = 0
        if self.ranks and decision.match >= 0 and not decision.ranking:
            best = best_candidates(row, descending=self.context.rows == "log_ratio")
            decision = replace(decision, ranking=tuple(best.tolist()))
        return decision

    def check_odometry(self) -> None:
        """Raise a WilocError naming ``odometry`` when this run cannot take a frame's odometry (a
        method that reads it checks its map here), before anything of the frame is decided."""

    def odometry_next(self) -> bool | None:
        """Whether the next frame must come with odometry (True), must come without (False), or
        may come either way (None, the default)."""
        return None

    @abstractmethod
    def prepare(self, context: MapContext) -> None:
        """Learn from the map what the method needs before the first query frame."""

    @abstractmethod
    def decide(self, row: NDArray[np.floating], odometry: float | None) -> Decision:
        """Query frame number ``self.frames``: its decision, updating what the method learns
        (the row float64, or float32 as the difference kernels give it)."""

    def ahead(self, rows: NDArray[np.floating]) -> Sequence[Any] | None:
        """What the method computes from each of these consecutive rows alone (no state of
        earlier frames), one item per row, before they are stepped: a batch run computes it
        for many rows at once, in a helper thread beside the steps (default: nothing)."""
        return None

    def _chunks_ahead(self, rows: Iterable[NDArray[np.floating]]
                      ) -> Iterator[tuple[NDArray[np.floating], Sequence[Any] | None]]:
        """Up to ``AHEAD_ROWS`` consecutive rows at a time, with their :meth:`ahead`."""
        for item in rows:
            block = as_row_dtype(np.asarray(item))
            if block.ndim not in (1, 2):
                raise ParameterError("rows", f"rows (1-D) or blocks of rows (2-D), got an item of shape {block.shape}: "
                                             "give one row as a list of it, or as a 1 x N array")
            block = block if block.ndim == 2 else block[None, :]
            for first in range(0, block.shape[0], AHEAD_ROWS):
                chunk = block[first:first + AHEAD_ROWS]
                yield chunk, self.ahead(chunk)

    def row_ahead(self, row: NDArray[np.floating]) -> Any:
        """In :meth:`decide`: :meth:`ahead`'s item of the row being decided, given by the caller
        or computed now."""
        given = getattr(self, "_ahead", None)
        if given is not None:
            return given
        computed = self.ahead(row[None, :])
        return None if computed is None else computed[0]

    @property
    def model(self) -> HistogramModel | None:
        """The probability model as learned so far (None for methods without one)."""
        return None

    def facts(self) -> dict[str, Any]:
        """What the run learned or derived that the results header records besides the parameters."""
        return {}

    def header(self) -> dict[str, Any]:
        """The results header's ``params``: the method, its declared parameters and its facts, a
        float fact with the results table's 9 significant digits (a learned value's last bits
        follow numpy's logarithm, whose vector loops differ between CPUs: SPEC section 11)."""
        facts = {key: float(f"{value:.9g}") if isinstance(value, float) else value for key, value in self.facts().items()}
        return {"method": self.name, **self.params.as_dict(), **facts}

    def state(self) -> dict[str, Any]:
        """Everything :meth:`restore` needs to continue with identical decisions: numpy arrays and
        JSON-ready values."""
        return {"frames": self.frames, "passed": self.passed, **self.save_state()}

    def restore(self, context: MapContext, state: Mapping[str, Any]) -> None:
        """Continue from a :meth:`state` taken in the same context."""
        self.context = context
        self.frames = int(state["frames"])
        self.passed = int(state.get("passed", 0))  # a state saved before frames passed were counted: none
        self.load_state(state)

    @abstractmethod
    def save_state(self) -> dict[str, Any]:
        """What the method learned so far (see :meth:`state`)."""

    @abstractmethod
    def load_state(self, state: Mapping[str, Any]) -> None:
        """Set what :meth:`save_state` returned."""

    def run(self, rows: Iterable[NDArray[np.floating]], n_frames: int,
            odometry: NDArray[np.float64] | None = None, progress: Progress | None = None,
            passed: NDArray[np.intp] | None = None) -> Decisions:
        """Step every row (``n_frames`` of them) and collect the decisions (after :meth:`start`);
        ``passed[k]``, when given, the query frames left out just before row k (:meth:`skip`).

        ``rows`` yields rows, or 2-D blocks of consecutive rows (as the difference kernels give
        them). A helper thread reads them ``AHEAD_ROWS`` at a time, with what the method
        computes of them :meth:`ahead`, while this thread steps the rows before."""
        steps: list[Decision] = []
        # closed as the loop ends, however it ends: the helper threads stop before this returns
        # or raises (Ctrl-C), never running on into the interpreter's exit
        with closing(computed_ahead(self._chunks_ahead(rows))) as chunks:
            for chunk, computed in chunks:
                if len(steps) + chunk.shape[0] > n_frames:
                    raise WilocError(self.name, f"more difference rows than n_frames={n_frames}")
                for i, row in enumerate(chunk):
                    k = len(steps)
                    if passed is not None and passed[k] > 0:
                        self.skip(int(passed[k]))
                    steps.append(self.step(row, None if odometry is None else float(odometry[k]),
                                           None if computed is None else computed[i]))
                    if progress is not None:
                        progress(k + 1, n_frames)
        if len(steps) != n_frames:
            raise WilocError(self.name, f"got {len(steps)} difference rows, expected n_frames={n_frames}")
        return Decisions.collect(steps, self.columns, ranked=self.ranks, model=self.model, params=self.header())


def as_row_dtype(rows: NDArray[Any]) -> NDArray[np.floating]:
    """Difference rows as methods read them: float32 (as the kernels give them) kept, every other
    dtype (float16, integers) as float64."""
    return rows if rows.dtype == np.float32 else rows.astype(np.float64, copy=False)


def checked_step(odometry: object, frame: int) -> float:
    """A query frame's odometry step (the distance travelled since the previous frame) as a float:
    a real number, finite and >= 0; anything else (text, a list, True, NaN, a negative step) a
    WilocError naming ``odometry``, raised before the method's state changes."""
    if isinstance(odometry, bool) or not isinstance(odometry, (int, float, np.integer, np.floating)):
        raise WilocError(None, f"query frame {frame}: the step must be a number, got {type(odometry).__name__} "
                               f"{odometry!r}", parameter="odometry")
    step = float(odometry)
    if not (math.isfinite(step) and step >= 0):
        raise WilocError(None, f"query frame {frame}: the step must be finite and >= 0, got {odometry}",
                         parameter="odometry")
    return step
