"""Calibration in `wiloc evaluate` and `wiloc compare`: --cuts, --calibration-plot, the fixed-cut
table and Table II over results files from different maps."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from wiloc import api
from wiloc.cli import app

runner = CliRunner()
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _results(path: Path, query: str, reference: str, ref_names: list[str], method: str,
             rows: list[tuple[str, str, float]], new_place: list[float] | None = None) -> Path:
    """A results file in the documented format: (frame, match or "", confidence or NaN) per row,
    and each frame's P(new place) (NaN: an empty cell) when given."""
    header = {"wiloc-results": "1", "method": method, "descriptor": "sad", "mode": "map", "query": query,
              "map": reference, "exclude_recent": "0", "frames": str(len(rows)),
              "reference_frames": json.dumps(ref_names)}
    lines = [f"# {key}: {value}" for key, value in header.items()]
    lines.append("frame,match,difference,confidence,stage" + (",new_place" if new_place else ""))
    for k, (frame, match, confidence) in enumerate(rows):
        decided = bool(match) and not math.isnan(confidence)
        extra = "" if not new_place else "," + ("" if math.isnan(new_place[k]) else str(new_place[k]))
        lines.append(f"{frame},{match},{0.5 if decided else ''},{confidence if decided else ''},"
                     f"{'update' if decided else 'init'}{extra}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _gardens(folder: Path, method: str = "online", new_place: list[float] | None = None) -> Path:
    """Map day_right of 10 frames; query day_left: 5 right at 0.95, 4 wrong at 0.6, one undecided,
    and a frame of a new place (no true match) accepted at 0.7."""
    names = [f"img{i}.png" for i in range(10)]
    rows = ([(names[i], names[i], 0.95) for i in range(5)] + [(names[i], names[0], 0.6) for i in range(5, 9)]
            + [(names[9], "", math.nan), ("new.png", names[0], 0.7)])
    return _results(folder / f"day_left-{method}.csv", "/data/gardens/day_left", "/data/gardens/day_right",
                    names, method, rows, new_place)


def _nordland(folder: Path, method: str = "online", dataset: str = "nordland") -> Path:
    """Another map, summer, of 20 frames; query winter: 6 right at 0.97, 14 wrong at 0.92."""
    names = [f"f{i:02d}.png" for i in range(20)]
    rows = [(names[i], names[i], 0.97) for i in range(6)] + [(names[i], names[0], 0.92) for i in range(6, 20)]
    return _results(folder / f"{dataset}-winter-{method}.csv", f"/data/{dataset}/winter",
                    f"/data/{dataset}/summer", names, method, rows)


def _json(result) -> object:
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def test_evaluate_reports_calibration_at_the_given_cuts(tmp_path: Path) -> None:
    path = _gardens(tmp_path)
    (row,) = _json(runner.invoke(app, ["evaluate", str(path), "--gt", "aligned", "--cuts", "0.6,0.7,0.95",
                                       "--json"]))["runs"]
    assert row["decided"] == 10 and row["with_true_match"] == 10
    # bins: 0.6 (4 frames, none right), 0.7 (the new place, wrong), 0.95 (5 frames, all right)
    assert row["ece"] == pytest.approx((4 * 0.6 + 0.7 + 5 * 0.05) / 10)
    assert row["brier"] == pytest.approx((4 * 0.36 + 0.49 + 5 * 0.0025) / 10)
    assert row["mean_confidence"] == pytest.approx(0.785) and row["share_correct"] == 0.5
    assert [(c["cut"], c["accepted"]) for c in row["cuts"]] == [(0.6, 10), (0.7, 6), (0.95, 5)]
    assert [c["precision"] for c in row["cuts"]] == pytest.approx([0.5, 5 / 6, 1.0])
    assert [c["recall"] for c in row["cuts"]] == pytest.approx([0.5, 0.5, 0.5])
    assert [b["count"] for b in row["reliability"]] == [0, 0, 0, 0, 0, 0, 4, 1, 0, 5]
    table = runner.invoke(app, ["evaluate", str(path), "--gt", "aligned", "--cuts", "0.6,0.7,0.95"])
    assert table.exit_code == 0, table.output
    for text in ("ECE", "0.335", "Brier score", "0.194", "cut 0.95", "P 0.833", "n 6"):
        assert text in table.stdout


def test_evaluate_default_cuts_accept_nothing_above_every_confidence(tmp_path: Path) -> None:
    (row,) = _json(runner.invoke(app, ["evaluate", str(_gardens(tmp_path)), "--json"]))["runs"]
    assert [c["cut"] for c in row["cuts"]] == [0.5, 0.9, 0.99]
    assert row["cuts"][2]["accepted"] == 0 and row["cuts"][2]["precision"] is None  # NaN -> null


def test_cuts_are_each_reported_once_in_order(tmp_path: Path) -> None:
    """--cuts 0.9,0.5,0.9: the cuts 0.5 and 0.9, in the table, the JSON and the CSV alike, where
    the JSON listed 0.9 twice and the CSV held it once."""
    path = _gardens(tmp_path)
    (row,) = _json(runner.invoke(app, ["evaluate", str(path), "--cuts", "0.9,0.5,0.9", "--json",
                                       "--csv", str(tmp_path / "m.csv")]))["runs"]
    assert [c["cut"] for c in row["cuts"]] == [0.5, 0.9]
    assert (tmp_path / "m.csv").read_text().splitlines()[0].count(",precision@") == 2
    table = runner.invoke(app, ["evaluate", str(path), "--cuts", "0.9,0.5,0.9"]).stdout
    assert table.count("cut 0.9 ") == 1 and table.index("cut 0.5") < table.index("cut 0.9")


def test_a_target_precision_given_twice_is_one_table_ii_row(tmp_path: Path) -> None:
    table2 = _json(runner.invoke(app, ["compare", str(_gardens(tmp_path)), str(_nordland(tmp_path)),
                                       "--precision", "99,100,99", "--json"]))["table2"]
    assert [row["precision"] for row in table2] == [99.0, 99.0, 100.0, 100.0]  # per traversal, in the order given


@pytest.mark.parametrize("cuts", ["0.5,1.5", "abc", "0.9,", "-0.1", "nan", ""])
def test_bad_cuts_are_one_line_usage_errors(tmp_path: Path, cuts: str) -> None:
    path = _gardens(tmp_path)
    for command in ("evaluate", "compare"):
        result = runner.invoke(app, [command, str(path), "--cuts", cuts])
        if cuts == "0.9,":  # a trailing comma is forgiven, as in --precision
            assert result.exit_code == 0, result.output
            continue
        assert result.exit_code == 2, result.output
        assert len(result.stderr.strip().splitlines()) == 1 and "--cuts" in result.stderr
        assert "Traceback" not in result.output


@pytest.mark.parametrize(("command", "option", "name", "folder"), [
    ("evaluate", "--csv", "metrics.csv", "metrics.csv"), ("compare", "--csv", "metrics.csv", "metrics.csv"),
    ("evaluate", "--csv", "metrics.csv", "metrics-curves.csv"), ("evaluate", "--pr-plot", "pr.png", "pr.png"),
    ("compare", "--threshold-plot", "fig5.svg", "fig5.svg"), ("report", "-o", "report.html", "report.html")])
def test_an_output_file_where_a_folder_is_is_refused_before_any_work(tmp_path: Path, command: str, option: str,
                                                                     name: str, folder: str) -> None:
    """A folder where the file (or the curves beside --csv) would go is a usage error before any
    work, where it was found only when written: after the work, with a note that the folder was
    replaced, and with the metrics written but not their curves."""
    (tmp_path / folder).mkdir()
    result = runner.invoke(app, [command, str(_gardens(tmp_path)), option, str(tmp_path / name)])
    assert result.exit_code == 2, result.output
    assert result.stderr.strip().splitlines() == [result.stderr.strip()] and "Traceback" not in result.output
    assert result.stderr.startswith(f"error: {option if option != '-o' else '--out'}: ") and folder in result.stderr
    assert "replaced" not in result.stderr and (tmp_path / folder).is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({folder, "day_left-online.csv"})


@pytest.mark.parametrize("command", ["evaluate", "compare"])
def test_metrics_csv_and_its_curves_name_each_run_alike(tmp_path: Path, command: str) -> None:
    """--csv's metrics and the curves beside them join on ``results`` (the results file as given),
    where evaluate's metrics named a run by its label's short name and the curves by its path."""
    import pandas as pd

    files = [str(_gardens(tmp_path / "a")), str(_nordland(tmp_path / "b"))]
    result = runner.invoke(app, [command, *files, "--csv", str(tmp_path / "m.csv")])
    assert result.exit_code == 0, result.output
    metrics, curves = pd.read_csv(tmp_path / "m.csv"), pd.read_csv(tmp_path / "m-curves.csv")
    assert metrics["results"].tolist() == files and set(curves["results"]) == set(files)
    for run in metrics.itertuples():
        curve = curves[curves["results"] == run.results]
        gains = curve["recall"].diff().fillna(curve["recall"].iloc[0])
        assert run.auc == pytest.approx(float((gains * curve["precision"]).sum()))


@pytest.mark.parametrize(("command", "option", "name"), [
    ("evaluate", "--csv", "m.csv"), ("evaluate", "--pr-plot", "pr.png"), ("report", "-o", "report.html")])
def test_an_output_file_inside_a_file_is_refused_naming_it_no_folder(tmp_path: Path, command: str, option: str,
                                                                     name: str) -> None:
    """An output file whose folder is a file: a usage error saying so, where it said the folder
    did not exist while it was there."""
    (tmp_path / "notes").write_text("a file\n")
    result = runner.invoke(app, [command, str(_gardens(tmp_path)), option, str(tmp_path / "notes" / name)])
    assert result.exit_code == 2, result.output
    assert result.stderr.strip() == (f"error: {option if option != '-o' else '--out'}: {tmp_path / 'notes'} is not "
                                     "a folder (the file would go into it)")


def test_a_ground_truth_csv_given_without_its_form_is_read_as_its_first_line_says(tmp_path: Path) -> None:
    """A bare --gt FILE.csv is pairs, positions or a matrix as its header (or its numbers) shows,
    scored as the same file with its form named; every CSV was read as pairs, so a positions file
    or a matrix ended in 'missing column(s) query, reference'."""
    run = str(_gardens(tmp_path))
    names = [f"img{i}.png" for i in range(10)]
    (tmp_path / "pairs.csv").write_text("query,reference\n" + "".join(f"{n},{n}\n" for n in names[:8]))
    (tmp_path / "q.csv").write_text("name,x,y\n" + "".join(f"{n},{i}.0,0.0\n" for i, n in enumerate(names))
                                    + "new.png,100.0,0.0\n")
    (tmp_path / "r.csv").write_text("name,x,y\n" + "".join(f"{n},{i}.0,0.0\n" for i, n in enumerate(names)))
    np.savetxt(tmp_path / "m.csv", np.eye(11, 10, dtype=int), fmt="%d", delimiter=",")
    for kind, extra in (("pairs", []), ("positions", ["--gt-map", str(tmp_path / "r.csv"), "--radius", "0.5"]),
                        ("matrix", [])):
        path = tmp_path / {"pairs": "pairs.csv", "positions": "q.csv", "matrix": "m.csv"}[kind]
        named, bare = (_json(runner.invoke(app, ["evaluate", run, "--gt", gt, *extra, "--json"]))
                       for gt in (f"{kind}:{path}", str(path)))
        assert bare["ground_truth"] == named["ground_truth"] and bare["ground_truth"].startswith(kind)
        assert bare["runs"][0]["with_true_match"] == named["runs"][0]["with_true_match"] > 0
        assert bare["runs"][0]["recall_at_1"] == named["runs"][0]["recall_at_1"]


def test_calibration_plot_is_written(tmp_path: Path) -> None:
    plot = tmp_path / "plots" / "reliability.png"
    plot.parent.mkdir()  # an output file's folder must exist (docs/guide.md)
    result = runner.invoke(app, ["evaluate", str(_gardens(tmp_path)), str(_nordland(tmp_path)),
                                 "--calibration-plot", str(plot)])
    assert result.exit_code == 0, result.output
    assert plot.read_bytes()[:8] == PNG_SIGNATURE and "wrote" in result.stdout
    compare_plot = tmp_path / "compare.png"
    data = _json(runner.invoke(app, ["compare", str(_gardens(tmp_path)), "--calibration-plot", str(compare_plot),
                                     "--json"]))
    assert data["files"] == [str(compare_plot)] and compare_plot.read_bytes()[:8] == PNG_SIGNATURE


def test_compare_over_two_maps_prints_cut_tables_and_table2(tmp_path: Path) -> None:
    paths = [str(p) for method in ("online", "threshold")
             for p in (_gardens(tmp_path, method), _nordland(tmp_path, method))]
    data = _json(runner.invoke(app, ["compare", *paths, "--gt", "aligned", "--json"]))
    table2 = [row for row in data["table2"] if row["method"] == "online" and row["precision"] == 100.0]
    # One threshold for both maps: 0.95 keeps day_left exact (0.7 would take the new place) and
    # winter exact (0.92 would take its wrong matches).
    assert {row["threshold"] for row in table2} == {0.95}
    assert {row["traversal"]: (row["recall"], row["worst"]) for row in table2} == {
        "day_left": (0.5, False), "winter": (0.3, True)}
    calibration = {(row["method"], row["traversal"]): row for row in data["runs"]}
    assert set(calibration) == {(m, t) for m in ("online", "threshold") for t in ("day_left", "winter")}
    winter = calibration[("online", "winter")]
    assert winter["cuts"][1] == {"cut": 0.9, "precision": pytest.approx(6 / 20), "recall": pytest.approx(6 / 20),
                                 "accepted": 20}
    assert winter["mean_confidence"] == pytest.approx((6 * 0.97 + 14 * 0.92) / 20)

    result = runner.invoke(app, ["compare", *paths, "--gt", "aligned"])
    assert result.exit_code == 0, result.output
    text = result.stdout
    order = [text.index("Table I:"), text.index("fixed confidence cuts: day_left"),
             text.index("fixed confidence cuts: winter"), text.index("Table II")]
    assert order == sorted(order)
    assert "0.950" in text[order[3]:]  # the global threshold


def test_evaluate_and_compare_say_how_well_p_new_place_is_calibrated(tmp_path: Path) -> None:
    # P(new place): 0 on the 5 right frames, 0.3 on the 4 wrong ones, none on the undecided
    # frame, 0.8 on the frame of a new place (the only frame without a true match)
    said = [0.0] * 5 + [0.3] * 4 + [math.nan, 0.8]
    with_column, without = _gardens(tmp_path, "catgraph", said), _gardens(tmp_path, "online")
    runs = _json(runner.invoke(app, ["evaluate", str(with_column), str(without), "--json"]))["runs"]
    new_place = runs[0]["new_place"]
    assert new_place["ece"] == pytest.approx((4 * 0.3 + 0.2) / 10)
    assert new_place["brier"] == pytest.approx((4 * 0.09 + 0.04) / 10)
    assert new_place["mean_confidence"] == pytest.approx(0.2) and new_place["share_correct"] == pytest.approx(0.1)
    assert [(c["accepted"], c["precision"], c["recall"]) for c in new_place["cuts"]] == [
        (1, 1.0, 1.0), (0, None, 0.0), (0, None, 0.0)]
    assert runs[0]["ece"] == pytest.approx((4 * 0.6 + 0.7 + 5 * 0.05) / 10)  # the confidence's, as before
    assert "new_place" not in runs[1]  # a run that does not say P(new place)

    table = runner.invoke(app, ["evaluate", str(with_column), str(without)])
    assert table.exit_code == 0, table.output
    for text in ("P(new place): ECE", "0.140", "share without a true match", "P(new place) >= 0.5"):
        assert text in table.stdout
    wide = runner.invoke(app, ["evaluate", str(with_column), str(without)], env={"COLUMNS": "40"})  # runs down
    assert wide.exit_code == 0 and "P(new place) (ground truth" in wide.stdout

    data = _json(runner.invoke(app, ["compare", str(with_column), str(without), "--json"]))
    by_method = {row["method"]: row for row in data["runs"]}
    assert by_method["catgraph"]["new_place"]["ece"] == pytest.approx(0.14) and "new_place" not in by_method["online"]
    text = runner.invoke(app, ["compare", str(with_column), str(without)]).stdout
    assert "P(new place) (ground truth" in text and text.index("P(new place)") < text.index("Table II")


@pytest.mark.parametrize("command", ["evaluate", "compare"])
def test_metrics_csv_writes_counts_as_integers_empty_where_a_run_has_none(tmp_path: Path, command: str) -> None:
    """A run with P(new place) beside one without: new_place_accepted@c was written 1.0 (its
    column made float by the other run's missing value) where accepted@c was 1."""
    with_column = _gardens(tmp_path, "catgraph", [0.0] * 5 + [0.3] * 4 + [math.nan, 0.8])
    without = _gardens(tmp_path, "online")
    result = runner.invoke(app, [command, str(with_column), str(without), "--csv", str(tmp_path / "m.csv")])
    assert result.exit_code == 0, result.output
    header, *rows = [line.split(",") for line in (tmp_path / "m.csv").read_text(encoding="utf-8").splitlines()]
    cells = [dict(zip(header, row, strict=True)) for row in rows]
    by_method = {row["method"]: row for row in cells}
    assert [by_method[m]["new_place_accepted@0.5"] for m in ("catgraph", "online")] == ["1", ""]
    assert [by_method[m]["accepted@0.5"] for m in ("catgraph", "online")] == ["10", "10"]
    assert by_method["online"]["frames"] == "11"


def test_same_traversal_name_from_two_datasets_gets_distinct_labels(tmp_path: Path) -> None:
    paths = [_gardens(tmp_path), _nordland(tmp_path, dataset="nordland"),
             _nordland(tmp_path, dataset="other")]
    comparison = api.compare(paths, api.TruthSource(kind="aligned"), precisions=(100.0,))
    assert comparison.traversals == ["day_left", "nordland/winter", "other/winter"]
    assert comparison.labels == ["online"] * 3  # one method, so Table II has one threshold for all
    assert comparison.table2["traversal"].tolist() == comparison.traversals
    assert comparison.cut_table["traversal"].tolist() == comparison.traversals
    assert list(comparison.cut_table.columns[:2]) == ["method", "traversal"]
    assert comparison.cut_table["accepted@0.9"].tolist() == [5, 20, 20]
    assert list(api.reliability_series(comparison.evaluations)) == [
        "online day_left", "online nordland/winter", "online other/winter"]


def test_results_files_of_one_name_in_two_folders_get_distinct_labels(tmp_path: Path) -> None:
    paths = [_gardens(tmp_path / "before"), _gardens(tmp_path / "after", new_place=[0.0] * 10 + [0.9])]
    evaluations = [api.evaluate(p, api.TruthSource(kind="aligned")) for p in paths]
    assert api.method_labels(evaluations) == ["online [before]", "online [after]"]
    assert len(api.reliability_series(evaluations)) == 2
    assert list(api.new_place_series(evaluations)) == ["online [after] day_left"]
    plot = tmp_path / "reliability.png"
    result = runner.invoke(app, ["evaluate", *map(str, paths), "--calibration-plot", str(plot)])
    assert result.exit_code == 0, result.output
    assert plot.read_bytes()[:8] == PNG_SIGNATURE


def test_table_ii_takes_one_threshold_per_folder_of_runs_of_a_method(tmp_path: Path) -> None:
    """Runs of one method over the same traversals from two folders (two settings): each run was
    labelled by its file, so that Table II took a threshold per run, never one over a setting's
    traversals; runs of one folder now share a label and Table II's threshold."""
    a = [_gardens(tmp_path / "a"), _nordland(tmp_path / "a")]
    b = [_gardens(tmp_path / "b", new_place=[0.0] * 10 + [0.9]), _nordland(tmp_path / "b")]
    b[1].write_text(b[1].read_text().replace(",0.92,", ",0.93,", 1))  # another run, not a copy
    truth = api.TruthSource(kind="aligned")
    comparison = api.compare([*a, *b], truth, precisions=(100.0,))
    assert comparison.labels == ["online [a]", "online [a]", "online [b]", "online [b]"]
    groups = comparison.table2.groupby("method", sort=False)["traversal"].agg(list).to_dict()
    assert groups == {"online [a]": ["day_left", "winter"], "online [b]": ["day_left", "winter"]}
    alone = api.compare(a, truth, precisions=(100.0,)).table2
    assert comparison.table2[comparison.table2["method"] == "online [a]"]["threshold"].tolist() == \
        alone["threshold"].tolist()


def test_traversal_labels_keep_one_name_when_the_folder_is_the_same(tmp_path: Path) -> None:
    paths = [_gardens(tmp_path, "online"), _gardens(tmp_path, "threshold")]
    evaluations = [api.evaluate(p, api.TruthSource(kind="aligned")) for p in paths]
    assert api.traversal_labels(evaluations) == ["day_left", "day_left"]
    assert api.run_names(evaluations) == ["online day_left", "threshold day_left"]


def test_figures_keep_one_colour_per_method_when_traversal_folders_have_spaces(tmp_path: Path) -> None:
    from wiloc.figures.plots import threshold_figure

    names = [f"img{i}.png" for i in range(4)]
    rows = [(name, name, 0.9) for name in names]
    paths = [_results(tmp_path / f"{q}-{method}.csv", f"/data/gp/{q} walk", "/data/gp/day_right", names, method, rows)
             for q in ("day", "night") for method in ("online", "catgraph")]
    comparison = api.compare(paths, api.TruthSource(kind="aligned"))
    assert api.run_names(comparison.evaluations) == ["online day walk", "catgraph day walk", "online night walk",
                                                     "catgraph night walk"]
    fig = threshold_figure(api.threshold_series(comparison), marks=api.threshold_marks(comparison))
    drawn = {line.get_label(): (line.get_color(), line.get_linestyle()) for line in fig.axes[0].lines}
    assert {label: style for label, style in drawn.items() if "Table II" not in label} == {
        "online day walk": ("C0", "-"), "catgraph day walk": ("C1", "-"),
        "online night walk": ("C0", "--"), "catgraph night walk": ("C1", "--")}
    assert {label.split(":")[0]: colour for label, (colour, _) in drawn.items() if "Table II" in label} == {
        "online": "C0", "catgraph": "C1"}


def test_compare_markdown_and_latex_give_each_cut_with_compare_numbers(tmp_path: Path) -> None:
    paths = [_gardens(tmp_path, new_place=[0.0] * 10 + [0.9]), _nordland(tmp_path)]
    said = {run["traversal"]: run for run in _json(runner.invoke(app, ["compare", *map(str, paths), "--cuts", "0.7,0.95",
                                                                       "--json"]))["runs"]}
    markdown = runner.invoke(app, ["compare", *map(str, paths), "--cuts", "0.7,0.95", "--markdown"])
    assert markdown.exit_code == 0, markdown.output
    calibration, new_place = (part.split("\n\n**", 1)[0] for part in markdown.stdout.split("**Calibration", 1)[1]
                              .split("**P(new place)", 1))
    assert "| P@0.7 | R@0.7 | n@0.7 | P@0.95 | R@0.95 | n@0.95 |" in calibration
    assert set(said) == {"day_left", "winter"}
    for traversal, run in said.items():
        (row,) = [line for line in calibration.splitlines() if line.startswith(f"| {traversal} |")]
        shown = row.strip("| ").split(" | ")[-6:]
        expected = [value for cut in run["cuts"] for value in (cut["precision"], cut["recall"], cut["accepted"])]
        assert shown == ["-" if v is None else str(v) if isinstance(v, int) else f"{v:.3f}" for v in expected]
    (row,) = [line for line in new_place.splitlines() if line.startswith("| day_left |")]
    assert row.strip("| ").split(" | ")[-6:][2::3] == [str(cut["accepted"]) for cut in said["day_left"]["new_place"]["cuts"]]
    latex = runner.invoke(app, ["compare", *map(str, paths), "--cuts", "0.7", "--latex"])
    assert latex.exit_code == 0 and r"P@0.7 & R@0.7 & n@0.7 \\" in latex.stdout


def test_an_output_naming_a_results_file_read_is_refused_and_the_run_kept(tmp_path: Path) -> None:
    path = _gardens(tmp_path)
    run = path.read_bytes()
    for command in ("evaluate", "compare"):
        result = runner.invoke(app, [command, str(path), "--csv", str(path)])
        assert result.exit_code == 2 and result.stderr.startswith(f"error: --csv: {path} is one of the results files read")
        assert path.read_bytes() == run and not (tmp_path / "day_left-online-curves.csv").exists()


@pytest.mark.parametrize("command", ["evaluate", "compare"])
def test_metrics_csv_has_no_new_place_columns_when_no_run_says_it(tmp_path: Path, command: str) -> None:
    """compare wrote three empty new_place_accepted@c columns for runs of which none has P(new
    place); docs/formats.md: no columns when none does (evaluate wrote none)."""
    runs = [str(_gardens(tmp_path, method)) for method in ("online", "threshold")]
    result = runner.invoke(app, [command, *runs, "--csv", str(tmp_path / "m.csv")])
    assert result.exit_code == 0, result.output
    header = (tmp_path / "m.csv").read_text(encoding="utf-8").splitlines()[0].split(",")
    assert "accepted@0.5" in header and not [key for key in header if key.startswith("new_place")]


def test_evaluate_names_traversals_of_one_name_as_compare_does(tmp_path: Path) -> None:
    """Two datasets' winter: evaluate headed both columns "online / winter" and gave traversal
    "winter" in --json, where compare (and evaluate's own run label) said a/winter and b/winter."""
    runs = [str(_nordland(tmp_path, "online", dataset)) for dataset in ("a", "b")]
    evaluated = _json(runner.invoke(app, ["evaluate", *runs, "--json"]))["runs"]
    compared = _json(runner.invoke(app, ["compare", *runs, "--json"]))["runs"]
    assert [run["traversal"] for run in evaluated] == [run["traversal"] for run in compared] == ["a/winter", "b/winter"]
    text = runner.invoke(app, ["evaluate", *runs], terminal_width=200).stdout
    assert "a/winter" in text and "b/winter" in text
