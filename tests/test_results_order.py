"""A results file's rows out of their run's order (sorted by confidence, halves swapped) score as
the file the run wrote, under ground truth that counts frames by position; rows the run did not
write are refused, naming the line and the frame."""
from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import ends_in_one_error
from typer.testing import CliRunner

from wiloc.cli import app
from wiloc.decisions import Decisions
from wiloc.evaluation.results import make_results, write_results
from wiloc.evaluation.results_header import ResultsHeader

#: Frames in natural order (img2 before img10, which plain text sorting would swap).
NAMES = [f"img{i}.png" for i in range(1, 13)]
MAP_RUN = ResultsHeader(method="online", mode="map", query="/data/walk", map="/data/map", query_digest="0" * 64)
SEQUENCE_RUN = ResultsHeader(method="online", mode="sequence", query="/data/walk", query_digest="0" * 64)


def _write_run(path: Path, header: ResultsHeader, names: list[str] = NAMES) -> Path:
    """A run over frames ``names``, against a map of frames NAMES (sequence mode: its own frames),
    with confidences in no order along the route and every third match wrong, so that scoring its
    rows at other frames' truth changes its numbers. Against the map frame k matches map frame k
    (every third: k + 1); in sequence mode the frame three back (every third: two back), none of
    the first four."""
    k = np.arange(len(names))
    if header.sequence:
        match = np.where(k < 4, -1, k - 3 + (k % 3 == 2))
    else:
        match = np.where(k % 3 == 2, (k + 1) % len(names), k)
    decided = match >= 0
    decisions = Decisions(match=match, difference=np.where(decided, 0.1, np.nan),
                          confidence=np.where(decided, 0.4 + 0.05 * (k * 5 % len(names)), np.nan),
                          stage=np.where(decided, "update", "init"))
    refs = names if header.sequence else NAMES
    write_results(path, make_results(decisions, query_names=names, ref_names=refs, header=header))
    return path


def _edited(path: Path, edit: Callable[[list[str]], list[str]], name: str) -> Path:
    """A copy of the results file ``path`` with its rows (the lines after the column line) edited."""
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    table = next(i for i, line in enumerate(lines) if not line.startswith("# ")) + 1
    out = path.with_name(name)
    out.write_text("".join(lines[:table] + edit(lines[table:])), encoding="utf-8")
    return out


def _by_confidence(rows: list[str]) -> list[str]:
    return sorted(rows, key=lambda row: -float(row.split(",")[3] or -1))


def _halves_swapped(rows: list[str]) -> list[str]:
    return rows[len(rows) // 2:] + rows[:len(rows) // 2]


def _two_swapped(rows: list[str]) -> list[str]:
    return [rows[7], *rows[1:7], rows[0], *rows[8:]]


def _evaluated(path: Path, *gt: str) -> dict[str, Any]:
    """What ``wiloc evaluate --json`` prints of a run."""
    result = CliRunner().invoke(app, ["evaluate", str(path), *gt, "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)["runs"][0]


def _scores(path: Path, *gt: str) -> dict[str, Any]:
    """The numbers ``wiloc evaluate --json`` prints of a run (without the file's name and warnings)."""
    return {key: value for key, value in _evaluated(path, *gt).items() if key not in ("results", "truth_warnings")}


@pytest.fixture
def identity(tmp_path: Path) -> str:
    """Matrix ground truth: the i-th query frame is the i-th map frame (natural order)."""
    path = tmp_path / "truth.npy"
    np.save(path, np.eye(len(NAMES), dtype=np.uint8))
    return str(path)


@pytest.mark.parametrize("edit", [_by_confidence, _halves_swapped, _two_swapped])
@pytest.mark.parametrize("gt", [("--gt", "matrix:{m}"), ("--gt", "aligned:index", "--tolerance", "0")])
def test_a_batch_runs_rows_in_another_order_score_as_the_file_the_run_wrote(tmp_path: Path, identity: str,
                                                                           edit: Callable, gt: tuple[str, ...]) -> None:
    """Ground truth that counts frames by position (a matrix; aligned by index, for names that are
    no numbers) read the rows by their place in the file: sorted by confidence, every row was
    scored against another frame's truth, without a word."""
    gt = tuple(part.format(m=identity) for part in gt)
    written = _write_run(tmp_path / "walk-sad-online.csv", MAP_RUN)
    edited = _edited(written, edit, "edited.csv")
    expected = _scores(written, *gt)
    assert 0.0 < expected["recall_at_1"] < 1.0  # the run's wrong matches are counted wrong, its right ones right
    assert _scores(edited, *gt) == expected
    assert _evaluated(written, *gt)["truth_warnings"] == []
    assert [w for w in _evaluated(edited, *gt)["truth_warnings"] if "rows are out of their run's order" in w]


def test_a_sequence_runs_rows_in_another_order_score_as_the_file_the_run_wrote(tmp_path: Path) -> None:
    """In sequence mode the earlier frames a match may name are counted in the run's own order
    (its header's reference_frames): swapped halves were refused with a message naming no file."""
    written = _write_run(tmp_path / "walk-sad-online.csv", SEQUENCE_RUN)
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("query,reference\n" + "".join(f"{q},{r}\n" for q, r in zip(NAMES[3:], NAMES)), encoding="utf-8")
    gt = ("--gt", f"pairs:{pairs}")
    expected = _scores(written, *gt)
    assert 0.0 < expected["recall_at_1"] < 1.0
    assert _scores(_edited(written, _halves_swapped, "edited.csv"), *gt) == expected


def test_a_row_of_a_frame_the_sequence_run_does_not_have_is_refused_naming_the_line(tmp_path: Path) -> None:
    written = _write_run(tmp_path / "walk-sad-online.csv", SEQUENCE_RUN)
    edited = _edited(written, lambda rows: [rows[0].replace("img1.png", "img99.png", 1), *rows[1:]], "edited.csv")
    first_row = written.read_text(encoding="utf-8").splitlines().index("frame,match,difference,confidence,stage") + 2
    result = CliRunner().invoke(app, ["evaluate", str(edited), "--gt", "aligned"])
    ends_in_one_error(result, 1, f"{edited}: line {first_row}: frame 'img99.png' is not one of the run's frames")


def test_a_frame_of_a_sequence_run_without_its_row_is_refused_naming_it(tmp_path: Path) -> None:
    """A row dropped, and the header's count edited to agree: the frame listed without a row."""
    written = _write_run(tmp_path / "walk-sad-online.csv", SEQUENCE_RUN)
    lines = written.read_text(encoding="utf-8").splitlines(keepends=True)
    kept = "".join(line for line in lines if not line.startswith("img5.png,"))
    edited = tmp_path / "edited.csv"
    edited.write_text(kept.replace(f"# frames: {len(NAMES)}", f"# frames: {len(NAMES) - 1}"), encoding="utf-8")
    result = CliRunner().invoke(app, ["evaluate", str(edited), "--gt", "aligned"])
    ends_in_one_error(result, 1, f"{edited}: no row for frame 'img5.png', which its header's reference_frames")


def test_a_frame_renamed_in_a_batch_runs_file_is_said_naming_its_line(tmp_path: Path, identity: str) -> None:
    """A renamed frame takes its new name's place in the frames' natural order, moving the rows
    between: the warning names the count and the first row out of place, as the file holds it."""
    written = _write_run(tmp_path / "walk-sad-online.csv", MAP_RUN)
    edited = _edited(written, lambda rows: [rows[0].replace("img1.png", "img99.png", 1), *rows[1:]], "edited.csv")
    first_row = written.read_text(encoding="utf-8").splitlines().index("frame,match,difference,confidence,stage") + 2
    warnings = _evaluated(edited, "--gt", f"matrix:{identity}")["truth_warnings"]
    assert warnings == [f"{len(NAMES)} of {len(NAMES)} rows are out of their run's order (its frames' natural order), "
                        f"the first at line {first_row}, frame 'img99.png': scored in the run's order"]


def test_a_run_that_records_no_order_keeps_its_rows_order(tmp_path: Path, identity: str) -> None:
    """A frame-by-frame or followed run (no query digest against a map) decided its frames in the
    order they came, which its rows keep: that order, not the names', is the one positions count."""
    arrival = [NAMES[1], NAMES[0], *NAMES[2:]]  # img2.png came first
    k = np.arange(len(NAMES))
    decisions = Decisions(match=k, difference=np.full(k.size, 0.1), confidence=np.linspace(0.99, 0.4, k.size),
                          stage=np.full(k.size, "update"))
    live = tmp_path / "live.csv"
    header = ResultsHeader(method="online", mode="map", query="/data/walk", map="/data/map")
    write_results(live, make_results(decisions, query_names=arrival, ref_names=NAMES, header=header))
    run = _evaluated(live, "--gt", f"matrix:{identity}")
    assert run["recall_at_1"] == 1.0 and run["truth_warnings"] == []


def test_a_batch_run_on_imported_descriptors_keeps_its_rows_order(tmp_path: Path, identity: str) -> None:
    """An imported matrix's frames keep its rows' order, not their names' natural order: a batch
    run on it writes its rows so, and they are scored so, without a warning."""
    arrival = [NAMES[1], NAMES[0], *NAMES[2:]]
    k = np.arange(len(NAMES))
    decisions = Decisions(match=k, difference=np.full(k.size, 0.1), confidence=np.linspace(0.99, 0.4, k.size),
                          stage=np.full(k.size, "update"))
    path = tmp_path / "queries-external:cosine-online.csv"
    header = replace(MAP_RUN, descriptor="external:cosine", query="/data/queries.h5")
    write_results(path, make_results(decisions, query_names=arrival, ref_names=NAMES, header=header))
    run = _evaluated(path, "--gt", f"matrix:{identity}")
    assert run["recall_at_1"] == 1.0 and run["truth_warnings"] == []
