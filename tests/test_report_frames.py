"""`wiloc report --frames`: the page of a slice of each run's frames, as `wiloc evaluate --frames`
scores it: its tables, figures and frame browser over those frames, the slice said on the page."""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import PathCollection
from matplotlib.figure import Figure

from helpers import ends_in_one_error
from test_cli_output import OUTPUT_SCHEMA
import test_report
from test_report import _data, _report, assert_loads_without_errors, needs_chromium
from typer.testing import CliRunner

from wiloc.cli import app
from wiloc.figures import plots

runner = CliRunner()
runs = test_report.runs  # the fixture of two methods' runs, which the tests request by name


def _calibration_table(page: str) -> str:
    """The page's calibration table, as HTML."""
    found = re.search(r"<h3>Calibration and fixed confidence cuts</h3>\s*(<table.*?</table>)", page, re.DOTALL)
    assert found
    return found.group(1)


def _ece(run: Path, *options: str) -> float:
    """A run's ECE as ``wiloc evaluate --json`` gives it."""
    result = runner.invoke(app, ["evaluate", str(run), "--gt", "aligned", *options, "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)["runs"][0]["ece"]


def test_the_report_of_a_slice_covers_those_frames_and_says_so(runs: list[Path], tmp_path: Path) -> None:
    """The query runs 45 frames, its last 5 past the map's end: frames 30: are scored alone, in the
    tables (as evaluate scores them), the browser (with their images) and the page's line on them;
    the difference matrix, of a whole run, is left out and the page says why."""
    whole = _report(runs, tmp_path / "whole.html").read_text(encoding="utf-8")
    result = runner.invoke(app, ["report", *map(str, runs), "--gt", "aligned", "-o", str(tmp_path / "part.html"),
                                 "--frames", "30:"], env={"COLUMNS": "300"})
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[:2] == [f"{run}: frames 30: of 45 scored (15 frames)" for run in runs]
    part = (tmp_path / "part.html").read_text(encoding="utf-8")
    for run in runs:
        assert f'<p class="scope">{run}: frames 30: of 45 scored (15 frames)</p>' in part
        assert f'<p class="scope">{run}' not in whole
    ece, whole_ece = _ece(runs[0], "--frames", "30:"), _ece(runs[0])
    assert f"{ece:.3f}" != f"{whole_ece:.3f}"
    assert f"<td>{ece:.3f}</td>" in _calibration_table(part) and f"<td>{ece:.3f}</td>" not in _calibration_table(whole)
    for shown, all_of in zip(_data(part)["runs"], _data(whole)["runs"]):
        for key in ("frames", "match", "truth", "confidence", "correct", "has_match"):
            assert shown[key] == all_of[key][30:], key
        assert all(index >= 0 for index in shown["query_image"])  # the run's images, checked as the run's
    assert "no images in the frame browser" not in part
    assert "no difference matrix, drawn for the whole run only, and frames 30: of its 45 were scored" in part
    assert "no difference matrix" not in whole
    shown = runner.invoke(app, ["report", str(runs[0]), "--gt", "aligned", "-o", str(tmp_path / "part.html"),
                                "--frames", "30:", "--json"])
    assert shown.exit_code == 0, shown.output
    OUTPUT_SCHEMA.validate(json.loads(shown.stdout))
    assert json.loads(shown.stdout)["frame_slice"] == "30:"


@pytest.mark.parametrize(("frames", "shown"), [("30:", range(30, 45)), ("-5:", range(40, 45)), (":20", range(20))])
def test_a_slices_timelines_and_browser_number_its_frames_as_the_run_does(
        frames: str, shown: range, runs: list[Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The timelines of a slice's page drew its frames from 0 (30: as 0-14): every point, shaded
    span and the axis are at the run's frame numbers, and the browser's data numbers them so."""
    drawn: list[Figure] = []
    timeline_figure = plots.timeline_figure
    monkeypatch.setattr(plots, "timeline_figure", lambda *args, **kwargs: drawn.append(
        timeline_figure(*args, **kwargs)) or drawn[-1])
    page = _report(runs, tmp_path / "part.html", "--frames", frames).read_text(encoding="utf-8")
    assert len(drawn) == len(runs)
    for figure in drawn:
        top, bottom = figure.axes
        assert top.get_xlim() == (shown.start - 0.5, shown.stop - 0.5)
        for ax in (top, bottom):
            xs = np.concatenate([c.get_offsets()[:, 0] for c in ax.collections if isinstance(c, PathCollection)]
                                + [line.get_xdata() for line in ax.lines])  # the points and the lines
            assert set(xs.tolist()) == set(shown)
        # the frames past the map's end (40-44) shaded where shown
        assert [patch.get_x() for patch in top.patches] == ([39.5] if shown.stop > 40 else [])
    for run in _data(page)["runs"]:
        assert (run["first"], run["run_frames"], len(run["frames"])) == (shown.start, 45, len(shown))


@needs_chromium
def test_a_slices_browser_says_the_frames_number_in_the_run(runs: list[Path], tmp_path: Path) -> None:
    dom = assert_loads_without_errors(_report(runs[:1], tmp_path / "part.html", "--frames", "30:"))
    assert re.search(r'id="frame-info"[^>]*>frame 30 \(0-44\) ', dom)  # as the timeline numbers it
    whole = assert_loads_without_errors(_report(runs[:1], tmp_path / "whole.html"))
    assert re.search(r'id="frame-info"[^>]*>frame 0 \(0-44\) ', whole)


@pytest.mark.parametrize("edit", ["gone", "changed"])
def test_a_slices_images_are_shown_only_while_the_whole_run_is_the_folders(edit: str, runs: list[Path],
                                                                          tmp_path: Path) -> None:
    """A slice's frames are checked as the whole run's: a query image outside the slice gone or
    changed since the run leaves the browser without pictures, as it does the whole run's."""
    last = tmp_path / "route" / "query" / "img44.png"
    if edit == "gone":
        last.unlink()
    else:
        shutil.copyfile(tmp_path / "route" / "query" / "img0.png", last)
    page = _report(runs[:1], tmp_path / "part.html", "--frames", ":20").read_text(encoding="utf-8")
    assert "no images in the frame browser" in page and "no longer gives the descriptors" in page
    assert _data(page)["images"] == [] and len(_data(page)["runs"][0]["frames"]) == 20


def test_a_bad_slice_is_one_error_line_and_no_page(runs: list[Path], tmp_path: Path) -> None:
    for frames, said in (("1:2:3", "a step is not taken"), ("5", "give START:STOP"),
                         ("100:", "selects none of the 45 frames")):
        result = runner.invoke(app, ["report", str(runs[0]), "--gt", "aligned", "-o", str(tmp_path / "r.html"),
                                     "--frames", frames])
        ends_in_one_error(result, 2, "--frames", said)
        assert not (tmp_path / "r.html").exists()


def test_report_help_lists_frames() -> None:
    result = runner.invoke(app, ["report", "--help"], env={"COLUMNS": "200", "NO_COLOR": "1"})
    assert result.exit_code == 0
    assert "--frames" in result.stdout and "SLICE" in result.stdout
