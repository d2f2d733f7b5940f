"""`wiloc evaluate --frames` and `wiloc compare --frames`: every measure over a slice of each run's
frames, counted in the run's order (say the first 20, where a filter locks on, against the rest),
against the ground truth of the whole run cut to those frames."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import ends_in_one_error
from test_cli_output import OUTPUT_SCHEMA
from test_results_order import MAP_RUN, NAMES, SEQUENCE_RUN, _edited, _halves_swapped, _write_run
from typer.testing import CliRunner

from wiloc import api
from wiloc.cli import app
from wiloc.errors import ParameterError

runner = CliRunner()
ALIGNED = ("--gt", "aligned", "--tolerance", "0")  # frame k's true match is map frame k


def _evaluated(path: Path, *args: str) -> dict[str, Any]:
    """What ``wiloc evaluate --json`` prints."""
    result = runner.invoke(app, ["evaluate", str(path), *ALIGNED, *args, "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def _scores(run: dict[str, Any]) -> dict[str, Any]:
    """A run's numbers, without what names the file, the slice or the truth's warnings."""
    return {key: value for key, value in run.items()
            if key not in ("results", "truth_warnings", "frame_slice", "run_frames")}


def test_the_slice_after_the_first_frames_scores_those_frames_alone(tmp_path: Path) -> None:
    """The run of test_results_order: map frame k matched, every third match one frame on (wrong),
    confidence 0.4 + 0.05 (5k mod 12). Frames 6-11 (k = 6..11): 0.70 right, 0.95 right, 0.60
    wrong, 0.85 right, 0.50 right, 0.75 wrong. Rows in another order in the file score the same."""
    written = _write_run(tmp_path / "walk-sad-online.csv", MAP_RUN)
    whole = _evaluated(written)["runs"][0]
    shown = _evaluated(_edited(written, _halves_swapped, "swapped.csv"), "--frames", "6:")
    (run,) = shown["runs"]
    assert shown["frame_slice"] == "6:" and run["frame_slice"] == "6:" and run["run_frames"] == len(NAMES)
    assert (run["frames"], run["decided"], run["with_true_match"]) == (6, 6, 6)
    assert run["recall_at_1"] == pytest.approx(4 / 6)
    # bins: 0.5 (right), 0.6 (wrong), 0.7 (0.70 right, 0.75 wrong), 0.8 (0.85 right), 0.9 (0.95 right)
    assert run["ece"] == pytest.approx((0.5 + 0.6 + 2 * abs(0.5 - 0.725) + 0.15 + 0.05) / 6)
    assert run["brier"] == pytest.approx((0.3 ** 2 + 0.05 ** 2 + 0.6 ** 2 + 0.15 ** 2 + 0.5 ** 2 + 0.75 ** 2) / 6)
    assert [b["count"] for b in run["reliability"]] == [0, 0, 0, 0, 0, 1, 1, 2, 1, 1]
    assert run["ece"] != whole["ece"] and run["frames"] < whole["frames"]
    alone = _edited(written, lambda rows: rows[6:], "alone.csv")  # a file of those rows only
    alone.write_text(alone.read_text().replace(f"# frames: {len(NAMES)}", "# frames: 6"))
    assert _scores(run) == _scores(_evaluated(alone)["runs"][0])


def test_the_first_frames_and_the_rest_cover_every_frame_once(tmp_path: Path) -> None:
    written = _write_run(tmp_path / "walk-sad-online.csv", MAP_RUN)
    whole = _evaluated(written)["runs"][0]
    first, rest = (_evaluated(written, "--frames", frames)["runs"][0] for frames in (":5", "5:"))
    for key in ("frames", "decided", "with_true_match"):
        assert first[key] + rest[key] == whole[key]
    assert (first["frames"], rest["frames"]) == (5, len(NAMES) - 5)
    right = [run["recall_at_1"] * run["with_true_match"] for run in (first, rest, whole)]
    assert right[0] + right[1] == pytest.approx(right[2])
    last = _evaluated(written, "--frames", "-5:")["runs"][0]  # counted from the end, as in Python
    assert _scores(last) == _scores(_evaluated(written, "--frames", f"{len(NAMES) - 5}:")["runs"][0])


def test_a_sequence_runs_slice_keeps_each_frames_earlier_frames(tmp_path: Path) -> None:
    """Frame k's true match is frame k - 3 (pairs), matched by all but every third frame: frames
    6-11 are 4 of 6 right, their true matches (frames 3-8) partly outside the slice."""
    written = _write_run(tmp_path / "walk-sad-online.csv", SEQUENCE_RUN)
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("query,reference\n" + "".join(f"{q},{r}\n" for q, r in zip(NAMES[3:], NAMES)), encoding="utf-8")
    result = runner.invoke(app, ["evaluate", str(written), "--gt", f"pairs:{pairs}", "--frames", "6:", "--json"])
    assert result.exit_code == 0, result.output
    (run,) = json.loads(result.stdout)["runs"]
    assert (run["frames"], run["with_true_match"]) == (6, 6)
    assert run["recall_at_1"] == pytest.approx(4 / 6)


#: A run whose last three frames (in its order) are of places the map lacks: no ground truth covers them.
UNCOVERED = [*NAMES[:9], "new1.png", "new2.png", "new3.png"]


def _uncovering_truth(form: str, tmp_path: Path) -> tuple[list[str], str, str]:
    """Ground truth of the form ``form`` for a run of frames UNCOVERED against the map NAMES, where
    the frames new1-new3 have no true match: its options, the warning counting those frames (where
    it names, what it says) and, for positions, a row naming no frame of the run, warned of too."""
    if form == "aligned":
        return ["--gt", "aligned", "--tolerance", "0"], "aligned ground truth (by name)", \
            "query frames have no reference frame to align with"
    if form == "positions":
        query, ref = tmp_path / "walk.csv", tmp_path / "map.csv"
        query.write_text("name,x,y\n" + "".join(f"{n},{10 * k},0\n" for k, n in enumerate([*NAMES[:9], "gone.png"])))
        ref.write_text("name,x,y\n" + "".join(f"{n},{10 * k},0\n" for k, n in enumerate(NAMES)))
        return ["--gt", f"positions:{query}", "--gt-map", str(ref), "--radius", "1"], str(query), \
            "query frames have no ground-truth row (never a true match)"
    rows = np.empty((9, 2), dtype=object)  # vprbench: a row for each of the first nine frames
    for k in range(9):
        rows[k] = [k, [k]]
    np.save(path := tmp_path / "ground_truth_new.npy", rows)
    return ["--gt", f"vprbench:{path}"], str(path), "query frames have no row (never a true match)"


@pytest.mark.parametrize("form", ["aligned", "positions", "vprbench"])
def test_warnings_that_count_frames_count_the_frames_scored(form: str, tmp_path: Path) -> None:
    """The warnings counting frames without ground truth counted the whole run's ('3 of 12') when a
    slice was scored, the first six frames, all covered, among them. A warning about the ground
    truth's file (a positions row naming no frame of the run) is the whole run's whatever is scored."""
    written = _write_run(tmp_path / "walk-sad-online.csv", MAP_RUN, UNCOVERED)
    gt, where, what = _uncovering_truth(form, tmp_path)
    file_wide = [f"{where}: 1 of 10 ground-truth rows name no query frame"] if form == "positions" else []

    def warned(*frames: str) -> list[str]:
        result = runner.invoke(app, ["evaluate", str(written), *gt, *frames, "--json"])
        assert result.exit_code == 0, result.output
        shown = json.loads(result.stdout)
        assert shown["warnings"] == [f"warning: {written}: {line}" for line in shown["runs"][0]["truth_warnings"]]
        return shown["runs"][0]["truth_warnings"]

    assert sorted(warned()) == sorted([f"{where}: 3 of 12 {what}", *file_wide])
    assert warned("--frames", ":6") == file_wide
    assert sorted(warned("--frames", "6:")) == sorted([f"{where}: 3 of 6 {what}", *file_wide])
    assert sorted(warned("--frames", "8:10")) == sorted([f"{where}: 1 of 2 {what}", *file_wide])
    scored = api.evaluate(written, api.TruthSource(kind="aligned", tolerance=0), frames=":6")
    assert scored.truth.warnings == []


def test_the_table_and_compare_say_which_frames_were_scored(tmp_path: Path) -> None:
    written = _write_run(tmp_path / "walk-sad-online.csv", MAP_RUN)
    table = runner.invoke(app, ["evaluate", str(written), *ALIGNED, "--frames", "6:"], env={"COLUMNS": "200"})
    assert table.exit_code == 0, table.output
    assert f"frames 6: of {len(NAMES)} scored (6 frames)" in table.stdout
    other = _write_run(tmp_path / "night-sad-online.csv", replace(MAP_RUN, query="/data/night"))
    compared = runner.invoke(app, ["compare", str(written), str(other), *ALIGNED, "--frames", ":4", "--json"])
    assert compared.exit_code == 0, compared.output
    shown = json.loads(compared.stdout)
    assert shown["frame_slice"] == ":4" and [run["frames"] for run in shown["runs"]] == [4, 4]
    # each run says its slice and its frames, as evaluate's runs do (the schema's evaluated_run)
    assert [(run["frame_slice"], run["run_frames"]) for run in shown["runs"]] == [(":4", len(NAMES))] * 2
    OUTPUT_SCHEMA.validate(shown)
    assert "frame_slice" not in json.loads(runner.invoke(app, ["evaluate", str(written), "--json"]).stdout)


def test_the_output_schema_declares_the_slice_and_the_runs_frames(tmp_path: Path) -> None:
    """The keys --frames adds are in the schema of --json, with their types, and the output fits it."""
    shown = _evaluated(_write_run(tmp_path / "walk-sad-online.csv", MAP_RUN), "--frames", "6:")
    OUTPUT_SCHEMA.validate(shown)
    declared = OUTPUT_SCHEMA.schema["$defs"]["evaluated_run"]["properties"]
    assert OUTPUT_SCHEMA.schema["properties"]["frame_slice"]["type"] == declared["frame_slice"]["type"] == "string"
    assert declared["run_frames"]["type"] == "integer"
    assert not OUTPUT_SCHEMA.is_valid({**shown, "runs": [{**shown["runs"][0], "run_frames": "all"}]})


@pytest.mark.parametrize(("frames", "problem"), [
    ("a:b", "'a:b': give START:STOP"), ("1:2:3", "'1:2:3' (a step is not taken)"),
    ("1:3,5:7", "'1:3,5:7' (one slice is taken, not a list of them)"), ("20", "'20': give START:STOP"),
    ("1.5:", "'1.5:': give START:STOP"), ("300:", f"'300:' selects none of the {len(NAMES)} frames of the run "),
    ("8:4", f"'8:4' selects none of the {len(NAMES)} frames"),
])
def test_a_bad_slice_is_one_usage_error_naming_the_option(tmp_path: Path, frames: str, problem: str) -> None:
    written = _write_run(tmp_path / "walk-sad-online.csv", MAP_RUN)
    for command in ("evaluate", "compare"):
        result = runner.invoke(app, [command, str(written), *ALIGNED, "--frames", frames])
        ends_in_one_error(result, 2, f"--frames: {problem}")
    if "selects none" in problem:
        assert str(written) in result.stderr


def test_the_library_takes_a_slice_and_refuses_a_step(tmp_path: Path) -> None:
    written = _write_run(tmp_path / "walk-sad-online.csv", MAP_RUN)
    truth = api.TruthSource(kind="aligned", tolerance=0)
    scored = api.evaluate(written, truth, frames=slice(6, None))
    assert (scored.frame_slice, scored.run_frames, scored.summary.frames) == ("6:", len(NAMES), 6)
    assert scored.results.frames["frame"].tolist() == NAMES[6:] and scored.truth.query_names == NAMES[6:]
    with pytest.raises(ParameterError, match="without a step") as refused:
        api.evaluate(written, truth, frames=slice(0, 6, 2))
    assert refused.value.parameter == "frames"


def test_the_difference_matrix_of_a_whole_run_is_refused_with_a_slice(tmp_path: Path) -> None:
    """The difference matrix shows the whole run's frames (the example pairs a slice's: test_pairs_figure)."""
    written = _write_run(tmp_path / "walk-sad-online.csv", MAP_RUN)
    result = runner.invoke(app, ["evaluate", str(written), "--frames", "6:", "--matrix-plot", str(tmp_path / "f.png")])
    ends_in_one_error(result, 2, "--matrix-plot: applies to a whole run (without --frames) only")
    assert not (tmp_path / "f.png").exists()
