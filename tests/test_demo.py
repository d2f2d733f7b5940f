"""`wiloc demo`: the generated route and its ground truth, and the command's outputs."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from wiloc import demo
from wiloc.cli import app
from wiloc.evaluation.groundtruth import positions_truth

PLOTS = ("pr.png", "threshold.png", "model.png")


def _truth(demo_route: demo.DemoRoute, query: Path):
    names = sorted(p.name for p in query.iterdir())
    ref_names = sorted(p.name for p in demo_route.reference.iterdir())
    return positions_truth(demo_route.positions / f"{query.name}.csv",
                           demo_route.positions / f"{demo_route.reference.name}.csv", demo.RADIUS_M, names, ref_names)


def test_route_positions_name_every_frame(demo_route: demo.DemoRoute) -> None:
    for folder in (demo_route.reference, *demo_route.queries):
        positions = pd.read_csv(demo_route.positions / f"{folder.name}.csv")
        assert sorted(positions["name"]) == sorted(p.name for p in folder.iterdir())
        assert list(positions.columns) == ["name", "x", "y"]


def test_only_the_detour_leaves_the_map(demo_route: demo.DemoRoute) -> None:
    for query in demo_route.queries:
        truth = _truth(demo_route, query)
        assert truth.warnings == []
        has_match = truth.has_match()
        if query.name == "detour":
            assert 0 < has_match.sum() < has_match.size
            unmatched = pd.read_csv(demo_route.positions / "detour.csv")["y"].to_numpy()[~has_match]
            assert (unmatched == demo.DETOUR_Y_M).all()
        else:
            assert has_match.all()


def test_route_is_reproducible(demo_route: demo.DemoRoute, tmp_path: Path) -> None:
    again = demo.make_demo_route(tmp_path)
    for folder in (demo_route.reference, *demo_route.queries):
        first = sorted(folder.iterdir())
        assert [p.name for p in first] == sorted(p.name for p in (tmp_path / folder.name).iterdir())
        assert first[len(first) // 2].read_bytes() == (tmp_path / folder.name / first[len(first) // 2].name).read_bytes()
    assert again.queries[0].name == demo_route.queries[0].name


@pytest.fixture(scope="module")
def demo_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, str]:
    """`wiloc demo --json` given a relative --out, then the table view into the same folder (a rerun)."""
    out = tmp_path_factory.mktemp("demo")
    runner = CliRunner()
    here = os.getcwd()
    os.chdir(out.parent)
    try:
        as_json = runner.invoke(app, ["demo", "--out", out.name, "--json"])
    finally:
        os.chdir(here)
    assert as_json.exit_code == 0, as_json.output
    text = runner.invoke(app, ["demo", "--out", str(out)], terminal_width=200)
    assert text.exit_code == 0, text.output
    return out, json.loads(as_json.stdout), text.stdout


def test_demo_writes_results_tables_and_plots(demo_runs: tuple[Path, dict, str]) -> None:
    out, report, _ = demo_runs
    results = sorted((out / "results").glob("*.csv"))
    assert len(results) == len(demo.METHODS) * len(demo.DRIVES[1:])
    for name in ("table1.csv", "table2.csv", *PLOTS):
        assert (out / name).stat().st_size > 0
        assert str(out / name) in report["files"]  # absolute, as every --json path (docs/formats.md)
    assert report["out"] == str(out) and all(Path(p).is_absolute() and Path(p).is_file() for p in report["files"])
    for name in PLOTS:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"



def test_demo_json_is_compares_and_a_rerun_says_what_it_replaced(demo_runs: tuple[Path, dict, str]) -> None:
    """demo's --json gives its runs as compare's --json does (each with its ground truth's
    warnings, and the ground truth named); a demo run again into the same folder says, on stderr
    and in its --json, that it replaced each of its files."""
    out, report, _ = demo_runs
    assert report["ground_truth"] and all(run["truth_warnings"] == [] for run in report["runs"])
    again = CliRunner().invoke(app, ["demo", "--out", str(out), "--json"])
    assert again.exit_code == 0, again.output
    replaced = [f"note: replaced the existing file {path}" for path in json.loads(again.stdout)["files"]]
    assert json.loads(again.stdout)["warnings"] == replaced and len(replaced) == len(report["files"])


def test_demo_names_its_outputs_where_they_are(demo_runs: tuple[Path, dict, str]) -> None:
    """The closing line names each file by its path under --out: results files lie in results/."""
    out, _, text = demo_runs
    named = " ".join(text[text.index("demo outputs in"):].split()).split(": ", 1)[1].split(", ")
    assert all((out / name).is_file() for name in named) and "results/dusk-online.csv" in named


def test_demo_reports_online_worst_recall_at_global_threshold(demo_runs: tuple[Path, dict, str]) -> None:
    out, report, text = demo_runs
    rows = [r for r in report["table2"] if r["method"] == "online"]
    assert {r["traversal"] for r in rows} == {d.name for d in demo.DRIVES[1:]}
    for target in (100.0, 99.0):
        group = [r for r in rows if r["precision"] == target]
        worst = [r for r in group if r["worst"]]
        assert len(worst) == 1
        assert worst[0]["recall"] == min(r["recall"] for r in group)
        # the rerun printed the same recall, marked as the worst, in the online row of Table II
        line = next(line for line in text.splitlines()
                    if line.strip("│┃ ").startswith("online") and f"{target:g}%" in line)
        assert f"{worst[0]['recall']:.1%} *" in line
    pd.testing.assert_frame_equal(pd.read_csv(out / "table2.csv"), pd.DataFrame(report["table2"]),
                                  check_dtype=False)


def test_demo_methods_differ_and_recall_is_not_trivial(demo_runs: tuple[Path, dict, str]) -> None:
    _, report, _ = demo_runs
    table1 = pd.DataFrame(report["runs"])
    assert set(table1["method"]) == set(demo.METHODS)
    assert table1["recall_at_100"].min() < 1.0
    by_method = table1.groupby("method")["auc"].mean()
    assert by_method.nunique() == len(demo.METHODS)


def test_help_names_the_methods_the_demo_runs() -> None:
    """The demo runs demo.METHODS, not every method wiloc has (trained needs a labelled training
    pair, fabmap a vocabulary), so its help names them rather than promising every method."""
    shown = " ".join(CliRunner().invoke(app, ["demo", "--help"], terminal_width=200).stdout.split())
    assert "every method" not in shown
    assert all(method in shown for method in demo.METHODS)
