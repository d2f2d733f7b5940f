"""Output people can read: help pages, tables at 80 columns, one JSON key scheme, short reprs, and
a command line that starts without loading the heavy libraries."""
from __future__ import annotations

import collections
import json
import re
import subprocess
import sys
from importlib import resources
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from helpers import places, write_traversal
import typer
from typer.core import TyperArgument, TyperOption
from typer.testing import CliRunner

from wiloc import api
from wiloc.cli import app
from wiloc.cli.core import out
from wiloc.wrapping import Words

runner = CliRunner()
NARROW = {"COLUMNS": "80"}


def _route(tmp_path: Path, n: int = 24) -> tuple[Path, Path]:
    scenes = places(n)
    return (write_traversal(tmp_path / "ref", scenes, 1.0, 1), write_traversal(tmp_path / "query", scenes, 0.7, 2))


def _option_rows(text: str) -> dict[str, str]:
    """A help page's option rows, by long flag, each with its continuation lines."""
    rows: dict[str, str] = {}
    current = None
    for line in text.splitlines():
        match = re.match(r"│ (?:\*\s+)?(--[a-z0-9-]+)", line)
        if match:
            current = match.group(1)
            rows[current] = line
        elif line.startswith("│") and current:
            rows[current] += " " + line
        else:
            current = None
    return rows


def test_help_pages_name_arguments_show_every_default_and_no_type_placeholders() -> None:
    group = typer.main.get_command(app)
    pages = {"": group, **group.commands}
    for name, command in pages.items():
        text = runner.invoke(app, [*name.split(), "--help"], env={"COLUMNS": "400"}).stdout
        arguments = [p for p in command.params if isinstance(p, TyperArgument)]
        usage = " ".join(["Usage: wiloc", *name.split(), "[OPTIONS]",
                          *(p.metavar if p.required else f"[{p.metavar}]" for p in arguments)])
        assert usage in text, (name, text[:300])
        assert "<bool>" not in text and "<list[" not in text and not re.search(r"<\w+\[", text), name
        rows = _option_rows(text)
        for option in command.params:
            if isinstance(option, TyperOption) and not option.hidden:
                flag = next(o for o in option.opts if o.startswith("--"))
                assert flag in rows, (name, flag)
                if not option.is_flag:
                    assert "[default:" in rows[flag], (name, rows[flag])
    localize = runner.invoke(app, ["localize", "--help"], env={"COLUMNS": "200"}).stdout
    for default in ("[default: (all cores)]", "[default: 2000]", "[default: -3,3]", "[default: 100]",
                    "[default: (QUERY-DESCRIPTOR-METHOD.csv here)]", "[default: (the share of same-place samples)]"):
        assert default in localize
    assert "(online:" not in localize  # one default shown once, not per method
    assert "; default:" not in localize  # said where every default is said


def test_the_command_list_gives_each_command_one_whole_sentence() -> None:
    """`wiloc --help` lists each command by its help's first paragraph, whose line breaks it
    keeps: a break there left a sentence cut in the middle of the list."""
    group = typer.main.get_command(app)
    for name, command in group.commands.items():
        first = (command.help or "").strip().split("\n\n")[0]
        assert first and "\n" not in first, (name, first)


def test_the_command_line_loads_without_the_heavy_libraries() -> None:
    heavy = ("pandas", "scipy", "h5py", "cv2", "matplotlib", "numba", "wiloc.api")
    code = f"import sys, wiloc.cli; print([m for m in {heavy!r} if m in sys.modules])"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert result.stdout.strip() == "[]"


def test_cache_list_tells_entries_apart_at_80_columns(tmp_path: Path, cache_dir: Path) -> None:
    scenes = places(6)
    for parent in ("nordland", "gardens"):
        folder = write_traversal(tmp_path / parent / "winter", scenes, 1.0, 1)
        assert runner.invoke(app, ["describe", str(folder), "--jobs", "1"]).exit_code == 0
    assert runner.invoke(app, ["describe", str(folder), "--crop", "top-half", "--jobs", "1"]).exit_code == 0
    text = runner.invoke(app, ["describe", "--list"], env=NARROW).stdout
    assert "…" not in text and max(map(len, text.splitlines())) <= 80
    rows = [line for line in text.splitlines() if line.startswith("│") and "sad" in line]
    assert sorted(row.split("│")[1].strip() for row in rows) == ["gardens/winter", "gardens/winter", "nordland/winter"]
    assert sorted(row.split("│")[3].strip() for row in rows) == ["crop=top-half", "defaults", "defaults"]


def test_evaluate_with_seven_runs_stays_readable_at_80_columns(tmp_path: Path, cache_dir: Path) -> None:
    ref, query = _route(tmp_path)
    paths = []
    for method in ("online", "threshold", "catgraph"):
        for q in (query, ref):
            paths.append(tmp_path / f"{q.name}-{method}.csv")
            assert runner.invoke(app, ["localize", str(q), "--map", str(ref), "--method", method, "--out",
                                       str(paths[-1]), "--jobs", "1"]).exit_code == 0
    paths.append(tmp_path / "again.csv")  # the first run's method and traversal again, told apart by its file
    assert runner.invoke(app, ["localize", str(query), "--map", str(ref), "--bins", "50", "--out", str(paths[-1]),
                               "--jobs", "1"]).exit_code == 0
    result = runner.invoke(app, ["evaluate", *map(str, paths)], env=NARROW)
    assert result.exit_code == 0, result.output
    assert "…" not in result.stdout and max(map(len, result.stdout.splitlines())) <= 80
    for label in api.run_names([api.evaluate(p, api.TruthSource()) for p in paths]):
        assert all(word in result.stdout for word in label.split())


def _shown_text(item: Any) -> str:
    """What a printed table (or line) holds: title, caption, headers and cells, as text."""
    from rich.table import Table
    from rich.text import Text

    if isinstance(item, Table):
        parts = [item.title, item.caption, *(column.header for column in item.columns),
                 *(cell for column in item.columns for cell in column.cells)]
        return "".join(_shown_text(part) for part in parts if part is not None)
    return str(item) if isinstance(item, Words) else Text.from_markup(str(item)).plain


def _characters(text: str) -> collections.Counter[str]:
    """``text``'s characters but spaces, line breaks and box-drawing rules: what wrapping moves."""
    return collections.Counter(c for c in text if not c.isspace() and not "\u2500" <= c <= "\u257f")


def test_narrow_tables_fold_cells_and_lose_no_character(tmp_path: Path, cache_dir: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """At 50, 40 and 20 columns every command's tables show every character of every cell, title
    and caption (a cell too wide for its column folds onto more lines, none is cut or ends in
    an ellipsis); at 50 the numbers and percentages stay whole on their line."""
    ref, query = _route(tmp_path)
    paths = [tmp_path / f"{method}.csv" for method in ("online", "catgraph")]
    for path in paths:
        assert runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", path.stem, "--out",
                                   str(path), "--jobs", "1"]).exit_code == 0
    printed: list[Any] = []
    original = out.print

    def recording(*items: Any, **options: Any) -> None:  # what each command hands rich, then printed
        printed.extend(items)
        original(*items, **options)
    monkeypatch.setattr(out, "print", recording)
    commands = [["describe", str(query), "--jobs", "1"], ["describe", "--list"], ["describe", "--list-descriptors"],
                ["localize", str(query), "--map", str(ref), "--out", str(tmp_path / "again.csv")],
                ["evaluate", *map(str, paths)], ["compare", *map(str, paths)]]
    for columns in (50, 40, 20):
        for args in commands:
            printed.clear()
            result = runner.invoke(app, args, env={"COLUMNS": str(columns)})
            assert result.exit_code == 0, result.output
            assert max(map(len, result.stdout.splitlines())) <= columns, result.stdout
            assert _characters(result.stdout) == _characters("".join(map(_shown_text, printed))), \
                f"{args[0]} at {columns} columns:\n{result.stdout}"
            if columns == 50 and args[0] == "compare":
                runs = json.loads(runner.invoke(app, [*args, "--json"]).stdout)["runs"]
                numbers = {f"{run[key]:.1%}" for run in runs for key in ("recall_at_100", "recall_at_99",
                                                                        "recall_at_90")}
                numbers |= {f"{run[key]:.3f}" for run in runs for key in ("auc", "recall_at_1", "ece", "brier")}
                assert numbers <= set(result.stdout.split()), result.stdout


def _keys(value: Any, skip: frozenset[str] = frozenset({"params", "descriptor_params"})) -> set[str]:
    """Every key of a JSON value, except inside the parameter records (whose keys are names)."""
    if isinstance(value, dict):
        return {k for k in value} | {key for k, v in value.items() if k not in skip for key in _keys(v)}
    if isinstance(value, list):
        return {key for v in value for key in _keys(v)}
    return set()


def test_json_keys_are_snake_case_and_carry_the_warnings(tmp_path: Path, cache_dir: Path) -> None:
    ref, query = _route(tmp_path)
    (query / "img3.png").write_bytes(b"")
    out = tmp_path / "run.csv"
    outputs = []
    for args in (["describe", str(query), "--jobs", "1", "--json"], ["describe", "--list", "--json"],
                 ["localize", str(query), "--map", str(ref), "--out", str(out), "--json"],
                 ["localize", str(query), "--map", str(ref), "--out", str(out), "--json"],
                 ["evaluate", str(out), "--json"], ["compare", str(out), "--json"]):
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        outputs.append(json.loads(result.stdout))
    for output in outputs:
        assert all(re.fullmatch(r"[a-z][a-z0-9_]*", key) for key in _keys(output)), sorted(_keys(output))
    describe, _, _, replaced, evaluate, _ = outputs
    assert describe["warnings"] == [f"skipped: {query / 'img3.png'}: empty file (0 bytes)"]
    assert describe["results"][0]["folder"] == str(query.resolve())  # full paths in JSON, names in tables
    assert replaced["warnings"][-1] == f"note: replaced the existing results file {out}"
    assert set(evaluate) == {"command", "ground_truth", "runs", "files", "warnings"}


def test_reports_have_short_reprs(tmp_path: Path, cache_dir: Path) -> None:
    ref, query = _route(tmp_path, 40)
    report = api.describe([query], "sad", jobs=1)[0]
    run = api.localize(query, reference=ref, method="online")
    evaluation = api.evaluate(run, api.TruthSource())
    comparison = api.compare([run], api.TruthSource())
    for obj in (report, report.entry, run, run.decisions, run.results, evaluation, evaluation.truth,
                evaluation.summary, evaluation.curve, comparison):
        assert len(repr(obj)) < 500 and "\n" not in repr(obj), repr(obj)
    assert "ndarray(40 x 1152)" in repr(report.entry) and "<list of 40>" in repr(report.entry)
    np.testing.assert_array_equal(report.entry.data.shape, (40, 1152))


def test_short_reprs_show_numpy_scalars_and_paths_by_value() -> None:
    """A numpy scalar showed as its type and empty shape ('int64()'), a path over 60 characters
    as '<PosixPath>': the value, and the path's end (its file's name)."""
    from wiloc.reprs import brief

    long = Path("/data/" + "walks/" * 12 + "day_left-sad-online.csv")
    assert brief(long) == repr("..." + str(long)[-57:]) and brief(long).endswith("day_left-sad-online.csv'")
    assert brief(Path("runs/a.csv")) == "'runs/a.csv'"
    assert [brief(v) for v in (np.int64(3), np.float32(0.5), np.bool_(True))] == ["3", "0.5", "True"]


def test_localize_without_out_writes_nothing_and_evaluate_takes_the_run(tmp_path: Path, cache_dir: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    import wiloc

    ref, query = _route(tmp_path, 30)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    def files() -> set[Path]:
        return {p for p in tmp_path.rglob("*") if not p.is_relative_to(cache_dir)}
    before = files()
    run = wiloc.localize(query, reference=ref, method="threshold")
    assert run.path is None and not run.replaced
    assert files() == before and (cache_dir / "descriptors").is_dir()  # only the cache grew
    in_memory = wiloc.evaluate(run, api.TruthSource())
    assert in_memory.path is None and in_memory.name == "query-threshold"
    written = tmp_path / "run.csv"
    again = wiloc.localize(query, reference=ref, method="threshold", out=written)
    assert again.path == written and written.is_file()
    from_file = wiloc.evaluate(written, api.TruthSource())
    assert in_memory.summary.as_dict() == pytest.approx(from_file.summary.as_dict(), rel=1e-8)  # 9 digits in files
    np.testing.assert_array_equal(in_memory.correct, from_file.correct)
    assert wiloc.compare([run, written], api.TruthSource()).table1["recall_at_1"].nunique() == 1


def test_json_paths_are_absolute_when_relative_ones_were_given(tmp_path: Path, cache_dir: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/formats.md: in --json, paths are absolute (a script run elsewhere can find them)."""
    ref, query = _route(tmp_path, 30)
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    assert runner.invoke(app, ["localize", query.name, "--map", ref.name, "--method", "threshold", "-o", "run.csv",
                               "--jobs", "1"]).exit_code == 0
    evaluated = json.loads(runner.invoke(app, ["evaluate", "run.csv", "--csv", "metrics.csv", "--json"]).stdout)
    compared = json.loads(runner.invoke(app, ["compare", "run.csv", "--csv", "table.csv", "--json"]).stdout)
    reported = json.loads(runner.invoke(app, ["report", "run.csv", "-o", "report.html", "--json"]).stdout)
    paths = ([evaluated["runs"][0]["results"], compared["runs"][0]["results"], reported["results"][0]["file"]]
             + evaluated["files"] + compared["files"])
    assert paths[:3] == [str(tmp_path / "run.csv")] * 2 + [str(tmp_path / "report.html")]
    assert all(Path(p).is_absolute() and Path(p).is_file() for p in paths) and len(paths) == 7


def _json_warnings(documents: list[Any]) -> list[str]:
    """The ``warnings`` of a command's JSON documents: of each object, or of each object of a list
    (one per folder or query)."""
    objects = [item for doc in documents for item in (doc if isinstance(doc, list) else [doc])]
    return [line for item in objects for line in item.get("warnings", [])]


#: The JSON Schema of every command's --json, as the package ships it.
OUTPUT_SCHEMA = jsonschema.Draft202012Validator(
    json.loads((resources.files("wiloc") / "schema" / "output.schema.json").read_text(encoding="utf-8")))


def test_the_output_schema_is_a_valid_schema_that_refuses_the_old_shapes() -> None:
    jsonschema.Draft202012Validator.check_schema(OUTPUT_SCHEMA.schema)
    run = {"method": "online", "descriptor": "sad", "traversal": "day_left", "results": "/r.csv"}
    OUTPUT_SCHEMA.validate({"command": "localize", "runs": [run], "warnings": []})
    for old in ([run], {"command": "localize", "runs": [{**run, "method": "online/sad", "descriptor": 3}], "warnings": []},
                {"command": "describe", "results": [{"folder": "/f", "descriptor": "sad", "frames": 6, "shape": "6x1152",
                                                     "computed": 6, "reused": 0, "failed": 0, "images_per_second": 1.0,
                                                     "failed_frames": [], "ignored": []}], "warnings": []},
                {"command": "evaluate", "runs": [run], "warnings": [], "ground_truth": "aligned", "files": []}):
        assert not OUTPUT_SCHEMA.is_valid(old), old


def test_every_json_output_carries_the_lines_printed_on_stderr(tmp_path: Path, cache_dir: Path) -> None:
    ref, query = _route(tmp_path)
    (query / "img3.png").write_bytes(b"")  # a bad frame: skipped with a note
    live = tmp_path / "live"
    live.mkdir()
    for name in ("img0.png", "img1.png"):
        (live / name).write_bytes((query / name).read_bytes())
    (live / "img2.png").write_bytes((query / "img1.png").read_bytes()[:200])  # never decodes: left out
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("query,reference\nimg0.png,img0.png\nimg1.png,nowhere.png\n")
    out, csv = tmp_path / "run.csv", tmp_path / "metrics.csv"
    csv.write_text("old\n")
    commands = {
        "describe": ["describe", str(query), "--jobs", "1"],
        "describe --list": ["describe", "--list"],
        "vocabulary": ["vocabulary", str(query), "--words", "4", "--max-side", "96"],
        "localize": ["localize", str(query), "--map", str(ref), "--out", str(out), "--jobs", "1"],
        "localize again": ["localize", str(query), "--map", str(ref), "--out", str(out), "--jobs", "1"],
        "localize --follow": ["localize", str(live), "--map", str(ref), "--out", str(tmp_path / "live.csv"),
                              "--follow", "--idle", "3"],
        "evaluate": ["evaluate", str(out), "--gt", f"pairs:{pairs}", "--csv", str(csv)],
        "compare": ["compare", str(out), "--gt", f"pairs:{pairs}"],
        "report": ["report", str(out), "--gt", f"pairs:{pairs}", "-o", str(tmp_path / "report.html")],
        "describe --list-descriptors": ["describe", "--list-descriptors"],
        "demo": ["demo", "--out", str(tmp_path / "demo")],
    }
    said = {}
    for name, args in commands.items():
        result = runner.invoke(app, [*args, "--json"])
        assert result.exit_code == 0, (name, result.output)
        documents = [json.loads(line) for line in result.stdout.splitlines()] if "--follow" in args \
            else [json.loads(result.stdout)]
        on_stderr = [line.replace(" ", ": ", 1) for line in result.stderr.splitlines()]
        assert _json_warnings(documents) == on_stderr, name
        if "--follow" not in args:  # one document in the one shape (a followed run: one object per frame)
            OUTPUT_SCHEMA.validate(documents[0])
            assert documents[0]["command"] == args[0], name
        said[name] = on_stderr
    assert said["describe"] == [f"skipped: {query / 'img3.png'}: empty file (0 bytes)"]
    assert said["vocabulary"] and said["localize"] and said["evaluate"] and said["compare"] and said["report"]
    assert said["localize again"][-1] == f"note: replaced the existing results file {out}"
    assert [line.split(":")[0] for line in said["localize --follow"]] == ["skipped"]
    assert f"note: replaced the existing file {csv}" in said["evaluate"]


def test_json_names_frames_left_out_by_their_absolute_paths(tmp_path: Path, cache_dir: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Folders given relative to the working folder: --json's frame paths (localize's ``skipped``,
    vocabulary's ``failed``, the skipped lines in ``warnings`` and on stderr, a followed run's
    stream) are absolute, as docs/formats.md says; describe names the frame in its ``folder``; the
    line without --json names the frame as the folder was given."""
    _route(tmp_path)
    (tmp_path / "query" / "img3.png").write_text("not an image")
    bad = str((tmp_path / "query" / "img3.png").resolve())
    monkeypatch.chdir(tmp_path)

    def shown(*args: str) -> tuple[dict[str, Any], list[str]]:
        result = runner.invoke(app, [*args, "--json"])
        assert result.exit_code == 0, result.output
        if "--follow" in args:  # one object per line: the first holding warnings is the frame left out
            return next(d for d in map(json.loads, result.stdout.splitlines()) if "warnings" in d), []
        return json.loads(result.stdout), result.stderr.splitlines()

    run, stderr = shown("localize", "query", "--map", "ref", "--out", "run.csv", "--jobs", "1")
    assert [item[0] for item in run["runs"][0]["skipped"]] == [bad]
    assert run["warnings"] == [f"skipped: {bad}: {run['runs'][0]['skipped'][0][1]}"]
    assert stderr == [line.replace(": ", " ", 1) for line in run["warnings"]]
    made, _ = shown("vocabulary", "query", "--words", "4", "--max-side", "96")
    assert [item[0] for item in made["results"][0]["failed"]] == [bad] and made["warnings"][0].startswith(f"skipped: {bad}: ")
    described, _ = shown("describe", "query", "--jobs", "1")
    (row,) = described["results"]
    assert (row["folder"], [name for name, _ in row["failed_frames"]]) == (str(Path("query").resolve()), ["img3.png"])
    followed, _ = shown("localize", "query", "--map", "ref", "--out", "live.csv", "--follow", "--idle", "1")
    assert followed["warnings"][0].startswith(f"skipped: {bad}: ")
    table = runner.invoke(app, ["localize", "query", "--map", "ref", "--out", "run.csv", "--jobs", "1"])
    assert table.exit_code == 0 and table.stderr.startswith(f"skipped {Path('query', 'img3.png')}: "), table.output
    table = runner.invoke(app, ["describe", "query", "--jobs", "1"])  # was the absolute path
    assert table.exit_code == 0 and table.stderr.startswith(f"skipped {Path('query', 'img3.png')}: "), table.output
    assert f"skipped: {bad}: " in described["warnings"][0]


def _recalls_at_cuts(text: str) -> list[str]:
    """The recall lines of a table's cut cells (``R 0.250``, ``R -``), in order."""
    return re.findall(r"(?<![\w@])R (-|\d\.\d{3})", text)


def _catgraph_run(tmp_path: Path) -> Path:
    """A catgraph run (it says P(new place)) over :func:`_route`, every frame with a true match."""
    ref, query = _route(tmp_path)
    run = tmp_path / "run.csv"
    assert runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "catgraph", "--out", str(run),
                               "--jobs", "1"]).exit_code == 0
    return run


def test_a_recall_with_nothing_to_recall_is_undefined_not_0(tmp_path: Path, cache_dir: Path) -> None:
    """Recall at a cut over no frames is 0 / 0: "-" in the tables and null in --json, as precision
    when nothing is accepted. P(new place)'s on a route whose every frame has a true match (it
    showed R 0.000), the match's under a ground truth that gives no frame one."""
    run = _catgraph_run(tmp_path)
    nothing = tmp_path / "nothing.npy"
    np.save(nothing, np.zeros((24, 24), dtype=bool))
    for truth, (match, new) in {"aligned": (False, True), f"matrix:{nothing}": (True, False)}.items():
        evaluate = runner.invoke(app, ["evaluate", str(run), "--gt", truth], env=NARROW)
        compare = runner.invoke(app, ["compare", str(run), "--gt", truth], env=NARROW)
        assert evaluate.exit_code == 0 and compare.exit_code == 0, (evaluate.output, compare.output)
        at_match, at_new = (_recalls_at_cuts(part) for part in evaluate.stdout.split("P(new place) >= ", 1))
        compared = (_recalls_at_cuts(part) for part in compare.stdout.split("P(new place) (ground truth", 1))
        for recalls, undefined in ((at_match, match), (at_new, new), *zip(compared, (match, new))):
            assert len(recalls) == 3 and (recalls == ["-"] * 3) == undefined, (truth, evaluate.stdout, compare.stdout)
        (said,) = json.loads(runner.invoke(app, ["evaluate", str(run), "--gt", truth, "--json"]).stdout)["runs"]
        for cuts, undefined in ((said["cuts"], match), (said["new_place"]["cuts"], new)):
            assert all((cut["recall"] is None) == undefined for cut in cuts), cuts


def test_describe_says_what_its_rate_counts(tmp_path: Path, cache_dir: Path) -> None:
    """An imported descriptor matrix is read a row at a time, not decoded from images: its rate is
    rows/s (it was labelled images/s); a folder's stays images/s."""
    ref, _ = _route(tmp_path, 6)
    matrix = tmp_path / "features.npy"
    np.save(matrix, np.random.default_rng(0).random((6, 16)).astype(np.float32))
    imported = runner.invoke(app, ["describe", "--import", str(matrix)], env=NARROW)
    described = runner.invoke(app, ["describe", str(ref), "--jobs", "1"], env=NARROW)
    assert imported.exit_code == 0 and described.exit_code == 0, (imported.output, described.output)
    assert "rows/s" in imported.stdout and "images/s" not in imported.stdout, imported.stdout
    assert "images/s" in described.stdout and "rows/s" not in described.stdout, described.stdout


def test_compare_pads_every_table_within_its_edges(tmp_path: Path, cache_dir: Path) -> None:
    """The calibration table at fixed cuts kept no space inside its left and right edges when it
    had room ('│catgraph │ ... │ P 1.000│'), unlike every other table: fit() makes room by dropping
    the edges when the console is narrow."""
    run = _catgraph_run(tmp_path)
    compare = runner.invoke(app, ["compare", str(run)], env={"COLUMNS": "120"})
    assert compare.exit_code == 0, compare.output
    edged = [line for line in compare.stdout.splitlines() if line[:1] in "│┃"]
    assert any("P " in line for line in edged)  # the cut table is among them
    assert all(line[1] == " " and line[-2] == " " for line in edged), compare.stdout


def test_localize_reports_the_median_confidence_and_a_huge_one_stays_readable(tmp_path: Path,
                                                                               cache_dir: Path) -> None:
    """The localize summary's median confidence is the median of the decided frames' (the mean of
    the middle two for an even count), in the table and in --json; threshold's unbounded
    confidences (a tiny --normaliser) are shown in scientific notation, not as 300 digits."""
    from wiloc.cli.views import cell
    from wiloc.evaluation.results import read_results

    ref, query = _route(tmp_path)
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold",
                                 "--out", str(tmp_path / "t.csv"), "--json"])
    assert result.exit_code == 0, result.output
    frames = read_results(tmp_path / "t.csv").frames
    decided = frames["confidence"][frames["match"].notna() & (frames["match"] != "")]
    assert len(decided) % 2 == 0 and len(decided) > 0
    assert json.loads(result.stdout)["runs"][0]["median_confidence"] == pytest.approx(float(np.median(decided)))
    assert cell(-8.08e299) == "-8.080e+299" and cell(999999.5) == "999999.500" and cell(0.5) == "0.500"
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold",
                                 "--normaliser", "1e-300", "--out", str(tmp_path / "huge.csv")], env=NARROW)
    assert result.exit_code == 0, result.output
    assert re.search(r"-\d\.\d{3}e\+\d{3}", result.stdout) and not re.search(r"\d{20}", result.stdout)


def test_a_followed_run_on_a_terminal_says_why_it_ended_and_where_its_rows_are(monkeypatch: pytest.MonkeyPatch,
                                                                              tmp_path: Path) -> None:
    """Under the live table a terminal showed 'Ctrl-C stops' to the end: the line a run without a
    terminal ends with (why it ended, the counts, the results file) was never said there."""
    import io

    from rich.console import Console

    from wiloc.cli import localize_views
    from wiloc.decisions import Decision

    terminal = Console(file=io.StringIO(), force_terminal=True, width=120)
    monkeypatch.setattr(localize_views, "out", terminal)
    decisions = [Decision(match=k, difference=0.1, confidence=0.9, stage="track", frame=f"f{k}.jpg",
                          match_name=f"m{k}.jpg") for k in range(3)]
    run = type("Run", (), {"warnings": [], "path": tmp_path / "r.csv", "idle": 0.5, "resumed": 2,
                           "__iter__": lambda self: iter(decisions)})()
    localize_views.show_followed(tmp_path, run, as_json=False)
    shown = terminal.file.getvalue()
    assert "f2.jpg" in shown
    assert f"ended: no new frame for 0.5 s; 3 frames decided (2 resumed before), 0 left out; results in " \
           f"{(tmp_path / 'r.csv').absolute()}" in re.sub(r"\x1b\[[0-9;?]*[a-zA-Z]", "", shown)
