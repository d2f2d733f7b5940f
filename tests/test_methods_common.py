"""Checks every registered method must pass (as scikit-learn runs common checks over every
estimator), plus the example method of docs/architecture.md added the documented way."""
from __future__ import annotations

import copy
import json
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from wiloc import api, demo
from wiloc.cache.store import Cache
from wiloc.candidates import RANKED, finite_minimum
from wiloc.decisions import Decision, Decisions
from wiloc.description.differences import summarize
from wiloc.errors import ParameterError
from wiloc.localization.localizer import Localizer
from wiloc.methods import registry
from wiloc.methods.base import NEEDS, ROWS, MapContext, Method, TrainingRows
from wiloc.parameters import Parameters, declared, param
from wiloc.rows import ArrayRows


# --- the example of docs/architecture.md: one module (here inline) and one registry line ----------

@dataclass(frozen=True)
class RatioParams(Parameters):
    owner = "ratio"
    window: int = param(2, "Frames within +-window of the best match are the same place.", low=0)


class Ratio(Method):
    """Lowe's ratio test on whole images: confidence 1 - m / m2, m2 the best difference outside
    +-window of the best match."""

    name = "ratio"
    Params = RatioParams
    columns = ("second",)
    params: RatioParams

    def prepare(self, context: MapContext) -> None:
        pass

    def decide(self, row: np.ndarray, odometry: float | None) -> Decision:
        z, m = finite_minimum(row)
        if z < 0:
            return Decision(match=-1, difference=np.nan, confidence=np.nan, stage="none")
        others = row.copy()
        others[max(0, z - self.params.window):z + self.params.window + 1] = np.inf
        second = float(others.min()) if np.isfinite(others).any() else np.inf
        confidence = 1.0 - m / second if second > 0 and np.isfinite(second) else 0.0
        return Decision(match=z, difference=m, confidence=confidence, stage="update", extra={"second": second})

    def save_state(self) -> dict[str, Any]:
        return {}

    def load_state(self, state: Mapping[str, Any]) -> None:
        pass


@pytest.fixture
def with_ratio(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(registry.METHODS, "ratio", Ratio)  # the one registry line


ALL = [*registry.METHODS, "ratio"]


# --- synthetic map and query ---------------------------------------------------------------------

def _rows(truth: np.ndarray, n_map: int, rng: np.random.Generator) -> np.ndarray:
    offset = truth[:, None] - np.arange(n_map)[None, :]
    return 1.0 + 0.08 * rng.standard_normal((truth.size, n_map)) - 0.6 * np.exp(-0.5 * (offset / 1.5) ** 2)


def _context(method: Method, rng: np.random.Generator) -> MapContext:
    """A map of 80 places; rows are differences, or for a method reading FAB-MAP's evidence,
    their negation (high: alike)."""
    n_map = 80
    ref = ArrayRows(_rows(np.arange(n_map, dtype=np.float64), n_map, rng))
    labels = np.arange(50)[:, None] == np.arange(n_map)[None, :]  # strict: some best matches are wrong
    train = TrainingRows(list(_rows(np.arange(50, dtype=np.float64), n_map, rng)), labels)
    steps = np.diagonal(ref.array, 1).copy()
    return MapContext(sequence=False, exclude_recent=5, n_map=n_map, natural_max=2.0, rows=_kind(method),
                      map_summary=lambda: summarize(ref, 5), neighbours=lambda: steps, training=lambda: train)


def _kind(method: Method) -> str:
    return "differences" if "differences" in method.rows else "log_ratio"


def _query_for(method: Method, rng: np.random.Generator) -> np.ndarray:
    rows = _query(rng)
    return rows if _kind(method) == "differences" else -rows


def _query(rng: np.random.Generator) -> np.ndarray:
    """40 frames along the map; frames 17-22 repeat frame 16's image exactly (a frozen camera), so
    that a state saved at frame 20 is saved within a repeat."""
    rows = _rows(np.linspace(5.0, 70.0, 40), 80, rng)
    rows[17:23] = rows[16]
    return rows


def _method(name: str, **params: Any) -> Method:
    return registry.make_method(name, {"particles": 300, **params} if name == "catgraph" else params)


def _equal(a: Decisions, b: Decisions) -> None:
    for x, y in [(a.match, b.match), (a.difference, b.difference), (a.confidence, b.confidence),
                 (a.stage, b.stage)]:
        np.testing.assert_array_equal(x, y)
    assert a.columns.keys() == b.columns.keys()
    for name in a.columns:
        np.testing.assert_array_equal(a.columns[name], b.columns[name])
    assert (a.ranking is None) == (b.ranking is None)
    if a.ranking is not None:
        np.testing.assert_array_equal(a.ranking, b.ranking)


# --- the checks ----------------------------------------------------------------------------------

@pytest.mark.usefixtures("with_ratio")
@pytest.mark.parametrize("name", ALL)
def test_parameters_are_declared_with_help_and_validated(name: str) -> None:
    cls = registry.method_class(name)
    assert issubclass(cls.Params, Parameters) and cls.Params.__dataclass_params__.frozen
    assert set(cls.needs) <= set(NEEDS), f"{name} needs what no run provides: {set(cls.needs) - set(NEEDS)}"
    assert cls.rows and set(cls.rows) <= set(ROWS), f"{name} reads rows of an unknown kind: {cls.rows}"
    for d in declared(cls.Params):
        assert d.help, f"{name}.{d.name} has no help"
    with pytest.raises(ParameterError) as err:
        cls(no_such_parameter=1)
    assert err.value.parameter == "no_such_parameter" and name in err.value.problem
    for d in declared(cls.Params):
        if d.low is not None:
            with pytest.raises(ParameterError) as err:
                cls(**{d.name: (d.low - 1,) * (d.length or 1) if d.kind == "floats" else d.low - 1})
            assert err.value.parameter == d.name


def _as_numpy(value: Any) -> Any:
    """A parameter's value as a numpy user holds it: a scalar of numpy's, a tuple as an array."""
    return np.array(value) if isinstance(value, tuple) else np.array([value])[0]


@pytest.mark.usefixtures("with_ratio")
@pytest.mark.parametrize("name", ALL)
def test_numpy_and_list_values_are_stored_as_plain_python(name: str) -> None:
    """np.int64 from a sweep, an array or a list for a tuple: the same parameters as plain Python
    values give (equal, same hash), and JSON-ready, as results headers and saved states write them."""
    cls = registry.method_class(name)
    plain = cls.Params()
    given = {d.name: _as_numpy(d.default) for d in declared(cls.Params) if d.default is not None}
    as_numpy = cls.Params(**given)
    assert as_numpy == plain and hash(as_numpy) == hash(plain)
    assert json.loads(json.dumps(as_numpy.as_dict())) == plain.as_dict()
    tuples = {d.name: list(d.default) for d in declared(cls.Params) if d.kind == "floats" and d.default}
    assert cls.Params(**tuples) == plain
    whole = {d.name: int(d.default) for d in declared(cls.Params)  # 1 for 1.0, as a config file writes it
             if d.kind == "float" and isinstance(d.default, float) and d.default.is_integer()}
    whole |= {d.name: [int(v) if float(v).is_integer() else v for v in d.default]
              for d in declared(cls.Params) if d.kind == "floats" and d.default}
    assert json.dumps(cls.Params(**whole).as_dict()) == json.dumps(plain.as_dict())  # the header's text


@pytest.mark.usefixtures("with_ratio")
@pytest.mark.parametrize("name", ALL)
def test_batch_run_equals_stepping_and_records_every_parameter(name: str) -> None:
    rng = np.random.default_rng(1)
    context, query = _context(_method(name), rng), _query_for(_method(name), rng)
    batch_method = _method(name)
    batch_method.start(context)
    batch = batch_method.run(iter(query), len(query))
    stepper = _method(name)
    stepper.start(context)
    steps = [stepper.step(row) for row in query]
    _equal(batch, Decisions.collect(steps, stepper.columns, ranked=stepper.ranks))
    assert set(batch.columns) == set(stepper.columns)
    header = batch.params
    assert header["method"] == name
    assert {f.name for f in fields(stepper.Params)} <= set(header)
    assert batch.decided.mean() > 0.9


@pytest.mark.usefixtures("with_ratio")
@pytest.mark.parametrize("name", ALL)
def test_a_ranking_method_ranks_its_match_first_and_the_rest_by_its_row(name: str) -> None:
    rng = np.random.default_rng(3)
    method = _method(name)
    context, query = _context(method, rng), _query_for(method, rng)
    method.start(context)
    steps = [(row, method.step(row)) for row in query]
    if not method.ranks:
        assert all(d.ranking == () for _, d in steps)
        return
    if name == "catgraph":  # ranked by its posterior: the mode, then the nodes of most particle weight
        for _, d in steps:
            assert d.ranking[0] == d.match and len(set(d.ranking)) == len(d.ranking) <= RANKED
        return
    sign = -1.0 if context.rows == "log_ratio" else 1.0
    for row, d in steps:
        order = [int(i) for i in np.argsort(sign * row, kind="stable") if np.isfinite(row[i])]
        assert d.ranking == (tuple(order[:RANKED]) if d.match >= 0 else ())
        assert d.match < 0 or d.ranking[0] == d.match


@pytest.mark.usefixtures("with_ratio")
@pytest.mark.parametrize("name", ALL)
def test_state_restores_identical_later_decisions(name: str) -> None:
    rng = np.random.default_rng(2)
    context, query = _context(_method(name), rng), _query_for(_method(name), rng)
    whole = _method(name, **({"seed": 9} if name == "catgraph" else {}))
    whole.start(context)
    expected = [whole.step(row) for row in query]
    first = _method(name, **({"seed": 9} if name == "catgraph" else {}))
    first.start(context)
    for row in query[:20]:
        first.step(row)
    state = copy.deepcopy(first.state())
    resumed = _method(name, **({"seed": 9} if name == "catgraph" else {}))
    resumed.restore(context, state)
    assert resumed.frames == 20
    assert [resumed.step(row) for row in query[20:]] == expected[20:]


@pytest.mark.usefixtures("with_ratio")
def test_the_example_method_runs_through_localize_and_the_localizer(demo_route: demo.DemoRoute,
                                                                    tmp_path: Path) -> None:
    cache = Cache(tmp_path / "cache")
    run = api.localize(demo_route.queries[0], reference=demo_route.reference, method="ratio",
                       method_params={"window": 3}, out=tmp_path / "ratio.csv", cache=cache)
    assert run.results.frames.columns.tolist()[-2:] == ["second", "ranking"]  # a new method ranks by default
    assert run.results.header.params["window"] == 3
    loc = Localizer(demo_route.reference, method="ratio", window=3, cache=cache)
    first = loc.observe(min(demo_route.queries[0].iterdir()))
    assert first.match_name == run.results.frames["match"].iloc[0]
    assert f"{first.confidence:.9g}" == f"{run.decisions.confidence[0]:.9g}"


@pytest.mark.usefixtures("with_ratio")
@pytest.mark.parametrize("name", ALL)
def test_a_map_self_matrix_that_is_not_square_is_named(name: str) -> None:
    """run_on_rows with the map's differences to itself cut to half its columns (an N x M query
    matrix given in its place) was an IndexError from reading its diagonal: a ParameterError
    names map_self and the shape."""
    from wiloc.localization.array_run import run_on_rows

    method = _method(name)
    rng = np.random.default_rng(4)
    for wrong in (_rows(np.arange(80, dtype=np.float64), 80, rng)[:, :40], np.ones(80)):
        with pytest.raises(ParameterError) as err:
            run_on_rows(method, _query_for(method, rng), 40, map_self=wrong, exclude_recent=5, natural_max=2.0)
        assert err.value.parameter == "map_self" and f"got shape {wrong.shape}" in err.value.problem


@pytest.mark.usefixtures("with_ratio")
@pytest.mark.parametrize("name", ALL)
def test_rows_of_other_dtypes_decide_as_float64_and_a_nan_or_a_flat_row_is_named(name: str) -> None:
    """A batch of float16 rows was a numba NotImplementedError (step converted them, run did not);
    a NaN made online and threshold leave the frame undecided (argmin took it for the best) where
    catgraph refused it; one 1-D row given as ``rows`` was an IndexError on a 0-d item."""
    from wiloc.errors import WilocError

    rng = np.random.default_rng(1)
    context, query = _context(_method(name), rng), _query_for(_method(name), rng).astype(np.float16)
    runs = []
    for rows in (query, query.astype(np.float64)):
        method = _method(name)
        method.start(context)
        runs.append(method.run(iter(rows), len(rows)))
    _equal(*runs)
    method = _method(name)
    method.start(context)
    holed = query[0].astype(np.float64)
    holed[3] = np.nan
    with pytest.raises(WilocError) as err:
        method.step(holed)
    assert err.value.parameter == "row" and "NaN" in err.value.problem and method.frames == 0
    with pytest.raises(ParameterError) as flat:
        method.run(query[0], 1)
    assert flat.value.parameter == "rows"
