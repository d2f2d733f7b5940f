"""A streaming Localizer's decisions scored as a batch run's: ``Localizer.results()`` gives the
results (and, saved, the file) that ``wiloc.localize`` gives for the same frames, through a saved
and loaded, or pickled, localizer; ``wiloc evaluate`` reads the file."""
from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from wiloc import api, demo
from wiloc.cache.store import Cache
from wiloc.cli import app
from wiloc.decisions import Decision, Decisions
from wiloc.errors import ParameterError, WilocError
from wiloc.evaluation.results_header import read_header
from wiloc.localization import streamed
from wiloc.localization.localizer import Localizer
from wiloc.localization.run_files import read_run


def _table(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, comment="#", dtype=str, keep_default_na=False)


@pytest.mark.parametrize("method", ["catgraph", "online"])
def test_localizer_results_score_as_the_batch_run(demo_route: demo.DemoRoute, method: str, tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(streamed, "PACKED", 16)  # decisions packed into arrays many times over the run
    cache = Cache(tmp_path / "cache")
    query, truth = demo_route.queries[0], demo_route.truth()
    batch = api.localize(query, reference=demo_route.reference, method=method, method_params={"seed": 3},
                         out=tmp_path / "batch.csv", cache=cache)
    frames = sorted(query.iterdir())
    loc = Localizer(demo_route.reference, method=method, seed=3, cache=cache)
    for frame in frames[:50]:
        loc.observe(frame)
    loc.save(tmp_path / "state.npz")
    loc = Localizer.load(tmp_path / "state.npz", cache=cache)
    for frame in frames[50:90]:
        loc.observe(frame)
    loc = pickle.loads(pickle.dumps(loc))
    for frame in frames[90:]:
        loc.observe(frame)
    results = loc.results(query)
    path = results.save(tmp_path / "streamed.csv")

    pd.testing.assert_frame_equal(_table(path), _table(batch.path))
    (header, _), (batch_header, _) = read_header(path), read_header(batch.path)
    assert header.query_digest is None and batch_header.query_digest  # no query descriptors kept
    assert header.model == batch_header.model and header.params == batch_header.params
    for scored, expected in ((api.evaluate(path, truth), api.evaluate(batch.path, truth)),  # written, read back
                             (api.evaluate(results, truth), api.evaluate(batch, truth))):  # in memory
        np.testing.assert_equal(scored.summary.as_dict(), expected.summary.as_dict())  # NaN (empty bins) equal
        np.testing.assert_equal(scored.calibration.as_dict(), expected.calibration.as_dict())
        np.testing.assert_equal(scored.new_place.as_dict(), expected.new_place.as_dict())

    result = CliRunner().invoke(app, ["evaluate", str(path), "--gt", f"positions:{truth.path}", "--gt-map",
                                      truth.ref_path, "--radius", str(truth.radius), "--json"],
                                env={"WILOC_CACHE": str(tmp_path / "cache")})
    assert result.exit_code == 0, result.output
    run = json.loads(result.stdout)["runs"][0]
    assert run["frames"] == len(frames) and run["recall_at_1"] == expected.summary.recall_at_1 > 0.5


def test_results_in_sequence_mode_are_the_batch_run_of_the_same_rows(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    rows = rng.integers(0, 256, (30, 16)).astype(np.float32)[np.r_[np.arange(30), np.arange(30)]]
    names = [f"f{i:02d}" for i in range(len(rows))]
    np.save(tmp_path / "loop.npy", rows)
    (tmp_path / "names.txt").write_text("\n".join(names) + "\n")
    batch = api.localize(tmp_path / "loop.npy", metric="l1", query_names_file=tmp_path / "names.txt",
                         method="online", method_params={"init": 25}, cache=tmp_path / "cache")
    loc = Localizer(None, descriptor="external", descriptor_params={"metric": "l1", "length": 16},
                    method="online", init=25, cache=tmp_path / "cache")
    decisions = [loc.observe(row, name=name) for row, name in zip(rows, names)]
    assert loc.results().header.query == ""
    results = loc.results(tmp_path / "loop.npy")
    header, expected = results.header, batch.results.header
    assert (header.mode, header.descriptor, header.query) == ("sequence", "external:l1", expected.query)
    assert header.query_digest == expected.query_digest  # the frames observed are its candidates: kept
    assert header.reference_frames == tuple(names) and header.frames == len(rows)
    assert results.frames["match"].tolist() == [d.match_name for d in decisions]
    pd.testing.assert_frame_equal(_table(results.save(tmp_path / "loop.csv")), _table(batch.results.save(tmp_path / "b.csv")))
    assert read_run(tmp_path / "loop.csv").frames["match"].tolist() == [d.match_name for d in decisions]


def test_results_refuse_a_run_without_frames_and_a_query_that_is_no_path(tmp_path: Path) -> None:
    loc = Localizer(None, descriptor="external", descriptor_params={"metric": "l1", "length": 4},
                    cache=tmp_path / "cache")
    with pytest.raises(WilocError, match="^results: no frame observed yet"):
        loc.results()
    loc.observe(np.zeros(4))
    with pytest.raises(ParameterError, match="^query: one traversal") as raised:
        loc.results(query=["a", "b"])
    assert raised.value.parameter == "query"


def test_concatenated_decisions_are_collected_ones() -> None:
    steps = [Decision(match=k, difference=float(k), confidence=0.5, stage="update", new_place=0.1 * k,
                      ranking=tuple(range(k, k + 1 + k % 3))) for k in range(7)]
    whole = Decisions.collect(steps, ("new_place",), ranked=True)
    parts = [Decisions.collect(part, ("new_place",), ranked=True) for part in (steps[:2], steps[2:6], steps[6:])]
    joined = Decisions.concatenated(parts)
    for name in ("match", "difference", "confidence", "stage", "ranking"):
        np.testing.assert_array_equal(getattr(joined, name), getattr(whole, name))
    np.testing.assert_array_equal(joined.columns["new_place"], whole.columns["new_place"])


def test_runs_in_memory_without_a_query_are_labelled_as_one_unnamed_traversal(demo_route: demo.DemoRoute,
                                                                              tmp_path: Path) -> None:
    """Two methods' streaming runs of the same frames, their query not given, are one traversal
    of the tables (not one per method), and each run is named by it and its method, not by the
    method alone (``-online``)."""
    cache, truth = Cache(tmp_path / "cache"), api.TruthSource(by="index")  # found without the query
    runs = []
    for method in ("threshold", "online"):
        loc = Localizer(demo_route.reference, method=method, cache=cache)
        for frame in sorted(demo_route.queries[0].iterdir())[:40]:
            loc.observe(frame)
        runs.append(loc.results())
    compared = api.compare(runs, truth)
    assert [e.name for e in compared.evaluations] == ["unnamed-threshold", "unnamed-online"]
    assert compared.traversals == ["unnamed", "unnamed"] and compared.labels == ["threshold", "online"]
    assert set(compared.table1["traversal"]) == {"unnamed"}


def test_the_training_pair_is_recorded_by_its_resolved_path_as_query_and_map_are(
        demo_route: demo.DemoRoute, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A training pair given relative to the current folder was recorded as typed
    (``train_query: ../shared/data/...``), beside a query and map resolved: read from elsewhere
    the header named folders that are not there."""
    cache = Cache(tmp_path / "cache")
    monkeypatch.chdir(demo_route.reference.parent)
    pair = api.Training(Path(demo_route.queries[1].name), Path(demo_route.reference.name), demo_route.truth())
    batch = api.localize(demo_route.queries[0], reference=demo_route.reference, method="trained", training=pair,
                         out=tmp_path / "batch.csv", cache=cache)
    loc = Localizer(demo_route.reference, method="trained", training=pair, cache=cache)
    loc.observe(min(demo_route.queries[0].iterdir()))
    for header in (read_header(batch.path)[0], loc.results().header):
        assert header.train_query == str(demo_route.queries[1].resolve())
        assert header.train_map == str(demo_route.reference.resolve()) == header.map
