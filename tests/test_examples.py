"""The example scripts on the real datasets, and the numbers docs/results.md quotes from them.

Each example runs once (descriptor ``sad``, the scripts' default, which is what docs/results.md
checks) in a subprocess with a private cache; the markdown tables that
``examples/protocol.render_markdown`` makes from its ``summary.json`` must appear in what the
script printed and match the example's block in docs/results.md: the same tables and text, every
number within :data:`LAST_DIGIT_UNITS` / :data:`PERCENT_POINTS` of the quoted one. The quoted
numbers were computed on another machine, and the last digits of float sums, FFTs, BLAS products
and local features depend on the CPU; a changed method or protocol moves them further.
"""
from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest
from helpers import write_images

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = ("gardens_point", "nordland")
METHODS = ("online", "threshold", "trained", "catgraph")
QUERIES = {"gardens_point": {"day_left", "night_right"}, "nordland": {"winter"}}
#: A number may differ from the one docs/results.md quotes by this many units in its last printed
#: digit (0.007 against 0.008)...
LAST_DIGIT_UNITS = 1
#: ... and a percentage of frames (recall, R@K) by this many percentage points: one frame of
#: Gardens Point's 200 (7.0 against 7.5).
PERCENT_POINTS = 0.5
_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


def _unit(number: str) -> float:
    """One unit in the last printed digit: '0.9974' -> 1e-4, '12' -> 1, '1.5e-05' -> 1e-6."""
    mantissa, _, exponent = number.lower().partition("e")
    return 10.0 ** (int(exponent or 0) - len(mantissa.partition(".")[2]))


def _is_percent(header: str) -> bool:
    return "%" in header or header.startswith("R@") or header == "recall"


def assert_quotes(quoted: str, computed: str, doc_hint: str, cpu_dependent: tuple[str, ...] = ()) -> None:
    """Markdown tables ``quoted`` show ``computed`` (same text and shape; numbers within tolerance,
    except in rows whose first cell is one of ``cpu_dependent``: there only the text and shape)."""
    quoted_lines, computed_lines = quoted.splitlines(), computed.splitlines()
    assert len(quoted_lines) == len(computed_lines), f"docs/results.md is out of date: {doc_hint}"
    header: list[str] = []
    for quoted_line, computed_line in zip(quoted_lines, computed_lines):
        if not quoted_line.startswith("|"):
            header = []
        cells = [c.strip() for c in quoted_line.strip("|").split("|")]
        computed_cells = [c.strip() for c in computed_line.strip("|").split("|")]
        header = header or cells
        assert len(cells) == len(computed_cells), \
            f"docs/results.md is out of date ({computed_line!r}, quoted {quoted_line!r}): {doc_hint}"
        for column, want, got in zip(header, cells, computed_cells):
            assert _NUMBER.sub("#", want) == _NUMBER.sub("#", got), \
                f"docs/results.md is out of date ({got!r}, quoted {want!r}): {doc_hint}"
            if cells[0] in cpu_dependent:
                continue
            for a, b in zip(_NUMBER.findall(want), _NUMBER.findall(got)):
                tolerance = max(LAST_DIGIT_UNITS * _unit(a), PERCENT_POINTS if _is_percent(column) else 0.0)
                assert abs(float(a) - float(b)) <= tolerance * (1 + 1e-9), \
                    f"docs/results.md is out of date ({column}: {b}, quoted {a}): {doc_hint}"


def test_quoted_tables_allow_last_digits_and_one_frame_but_not_more() -> None:
    head = "| method | recall @100 % | AP | threshold |\n|---|---:|---:|---:|\n"
    quoted = head + "| FAB-MAP | 7.0 | 0.007 | 0.9974 |"
    assert_quotes(quoted, head + "| FAB-MAP | 7.5 | 0.008 | 0.9973 |", "")
    assert_quotes(quoted, head + "| FAB-MAP | 0.0 | 0.264 | 0.9 |", "", cpu_dependent=("FAB-MAP",))
    with pytest.raises(AssertionError, match="out of date"):
        assert_quotes(quoted, head + "| FAB-MAP | 0.0 | 0.264 |", "", cpu_dependent=("FAB-MAP",))
    for changed in ("| FAB-MAP | 6.0 | 0.007 | 0.9974 |", "| FAB-MAP | 7.0 | 0.009 | 0.9974 |",
                    "| FAB-MAP | 7.0 | 0.007 | 0.9976 |", "| CAT-Graph | 7.0 | 0.007 | 0.9974 |",
                    "| FAB-MAP | 7.0 | 0.007 | 0.9974 | 1 |"):
        with pytest.raises(AssertionError, match="out of date"):
            assert_quotes(quoted, head + changed, "")


def _protocol() -> ModuleType:
    spec = importlib.util.spec_from_file_location("protocol", REPO / "examples" / "protocol.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("threshold", [0.695072115, 0.130062217, 0.98929, 0.99951, 0.5, None])
def test_the_markdown_threshold_taken_as_a_cut_keeps_its_frame_as_the_cli_prints_it(threshold: float | None) -> None:
    """Table II's threshold in docs/results.md was rounded to nearest (0.695072115 as 0.6951: a
    cut there loses the frame that set it); it is written as the CLI's tables write it, rounded
    down (docs/evaluation.md)."""
    from wiloc.labels import threshold_text

    summary = {"table1": [], "calibration": [], "table2": [
        {"method": "threshold", "precision": 100, "threshold": threshold, "traversal": "day_left",
         "recall": 0.01, "worst": False}]}
    row = next(line for line in _protocol().render_markdown(summary).splitlines() if line.startswith("| threshold |"))
    printed = row.strip("|").split("|")[2].strip()
    assert printed == threshold_text(threshold), row
    assert threshold is None or float(printed) <= threshold, row


def test_the_guide_quotes_the_error_of_a_wrong_method_parameter_as_the_library_raises_it() -> None:
    """docs/guide.md's example of a wrong ``method_params`` name listed online's parameters
    without ``confidence``, which the library has since taken."""
    from wiloc.errors import ParameterError
    from wiloc.methods.registry import make_method

    with pytest.raises(ParameterError) as raised:
        make_method("online", {"bin": 50})
    assert f"(`{raised.value}`)" in (REPO / "docs" / "guide.md").read_text(encoding="utf-8")


def test_a_one_table_example_ends_on_ctrl_c_with_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """table1.py and loop_closure.py (protocol.run_table_script) end on Ctrl-C with 'error:
    interrupted' and exit code 130, as the wiloc command does, not with a traceback."""
    protocol = _protocol()

    def interrupted(data: Path, out: Path) -> dict:  # Ctrl-C as a library rewords it (a plain one would stop pytest)
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise RuntimeError("interrupted while loading") from exc

    monkeypatch.setattr(sys, "argv", ["table1.py", str(tmp_path), "--out", str(tmp_path / "out")])
    with pytest.raises(SystemExit) as ended:
        protocol.run_table_script("table1", "a one-table example", interrupted, lambda summary: "")
    assert ended.value.code == 130 and capsys.readouterr().err == "error: interrupted\n"


@pytest.mark.parametrize(("options", "said"), [
    (["--descriptors", "foo"], "error: --descriptors: unknown descriptor 'foo'; choose one of "),
    (["--descriptors", " , "], "error: --descriptors: no descriptor in ' , '; give names such as sad,gist"),
    (["--descriptors", "sad,bow"], "error: --descriptors: 'bow' depends on its vocabulary, which the examples "),
    (["--methods", "online"], "error: --methods: no such option of gardens_point.py (see --help)"),
    (["--out"], "error: --out: expected one argument")])
def test_a_bad_example_option_is_one_line_naming_it_before_anything_is_made(tmp_path: Path, options: list[str],
                                                                             said: str) -> None:
    """--descriptors foo made the output folder and its results/, then named the library's
    parameter ('descriptor: unknown descriptor'); argparse's problems were its usage lines."""
    for folder in ("day_right", "day_left", "night_right"):
        (tmp_path / "data" / "gardens-point-walking" / folder).mkdir(parents=True)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, str(REPO / "examples" / "gardens_point.py"), str(tmp_path / "data"),
                           *(["--out", str(out)] if options != ["--out"] else []), *options],
                          capture_output=True, text=True, env={**os.environ, "WILOC_CACHE": str(tmp_path / "cache")},
                          check=False)
    assert proc.returncode == 2 and proc.stderr.startswith(said), proc.stderr
    assert len(proc.stderr.splitlines()) == 1 and not out.exists()


def test_an_example_says_each_frame_it_left_out_once(tmp_path: Path) -> None:
    """A frame wiloc cannot decode is left out of every run and said once on stderr, as `wiloc
    localize` says it ('skipped PATH: why'); the examples left it out without a word."""
    root = tmp_path / "data" / "gardens-point-walking"
    for seed, folder in enumerate(("day_right", "day_left", "night_right")):
        write_images(root / folder, 12, seed=seed)
    bad = root / "day_left" / "img4.png"
    bad.write_text("garbage\n", encoding="utf-8")
    proc = subprocess.run([sys.executable, str(REPO / "examples" / "gardens_point.py"), str(tmp_path / "data"),
                           "--out", str(tmp_path / "out")], capture_output=True, text=True,
                          env={**os.environ, "WILOC_CACHE": str(tmp_path / "cache")}, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    said = [line for line in proc.stderr.splitlines() if line.startswith("skipped ")]
    assert said == [f"skipped {bad}: cannot decode image data"], proc.stderr


def test_table1_says_where_its_outputs_went(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """table1.py printed its tables but not where summary.json, pr.png and results/ went, as the
    other examples do."""
    table1 = _example("table1")
    out = tmp_path / "out"
    monkeypatch.setattr(table1, "run", lambda data, out: {"table": []})  # the lines name what the real run writes
    monkeypatch.setattr(sys, "argv", ["table1.py", str(tmp_path), "--out", str(out)])
    table1.main()
    wrote = [line for line in capsys.readouterr().out.splitlines() if line.startswith("wrote ")]
    assert wrote == [f"wrote {out / name}" for name in ("summary.json", "pr.png", "results")]


@pytest.fixture(scope="module")
def runs(data_root: Path, tmp_path_factory: pytest.TempPathFactory,
         real_data_cache: Path) -> dict[str, tuple[dict, str]]:
    """Each example's summary.json and printed output (one cache shared by both runs and table1's)."""
    tmp = tmp_path_factory.mktemp("examples")
    env = {**os.environ, "WILOC_CACHE": str(real_data_cache), "COLUMNS": "200"}
    done = {}
    for name in EXAMPLES:
        out = tmp / name
        proc = subprocess.run([sys.executable, str(REPO / "examples" / f"{name}.py"), str(data_root),
                               "--out", str(out)], capture_output=True, text=True, env=env, check=False)
        assert proc.returncode == 0, proc.stderr[-2000:]
        done[name] = (json.loads((out / "summary.json").read_text(encoding="utf-8")), proc.stdout)
    return done


@pytest.mark.realdata
@pytest.mark.slow  # each example script runs for minutes
@pytest.mark.parametrize("name", EXAMPLES)
def test_example_covers_every_method_and_query(runs: dict[str, tuple[dict, str]], name: str) -> None:
    summary, stdout = runs[name]
    pairs = {(row["method"], row["traversal"]) for row in summary["table1"]}
    assert pairs == {(m, q) for m in METHODS for q in QUERIES[name]}
    for row in summary["table1"]:
        assert 0.0 <= row["recall_at_100"] <= row["recall_at_99"] <= row["recall_at_90"] <= 1.0
    worst = [row for row in summary["table2"] if row["worst"]]
    reached = {(row["method"], row["precision"]) for row in summary["table2"] if row["threshold"] is not None}
    assert len(worst) == len(reached)  # one per method and target precision (100, 99) that a threshold reaches
    assert f"trained: {summary['trained_on']}" in stdout
    assert "summary.json" in stdout


@pytest.mark.realdata
@pytest.mark.slow  # each example script runs for minutes
@pytest.mark.parametrize("name", EXAMPLES)
def test_results_doc_quotes_the_examples(runs: dict[str, tuple[dict, str]], name: str) -> None:
    summary, stdout = runs[name]
    protocol = _protocol()
    tables = protocol.render_markdown(summary)
    assert tables in stdout
    quoted = protocol.block_in((REPO / "docs" / "results.md").read_text(encoding="utf-8"), name)
    assert_quotes(quoted, tables, f"run examples/{name}.py --update-docs")


def _run_example(name: str, data_root: Path, tmp_path_factory: pytest.TempPathFactory,
                 cache: Path) -> tuple[dict, str]:
    """examples/NAME.py's summary.json and printed output, on ``cache``."""
    tmp = tmp_path_factory.mktemp(name)
    env = {**os.environ, "WILOC_CACHE": str(cache), "COLUMNS": "200"}
    proc = subprocess.run([sys.executable, str(REPO / "examples" / f"{name}.py"), str(data_root), "--out",
                           str(tmp / "out")], capture_output=True, text=True, env=env, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads((tmp / "out" / "summary.json").read_text(encoding="utf-8")), proc.stdout


def _example(name: str) -> ModuleType:
    """examples/NAME.py as a module (its ``render`` makes the table docs/results.md quotes)."""
    spec = importlib.util.spec_from_file_location(name, REPO / "examples" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    sys.path.insert(0, str(REPO / "examples"))
    try:
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(REPO / "examples"))
    return module


@pytest.fixture(scope="module")
def table1(data_root: Path, tmp_path_factory: pytest.TempPathFactory, real_data_cache: Path) -> tuple[dict, str]:
    return _run_example("table1", data_root, tmp_path_factory, real_data_cache)


@pytest.mark.realdata
@pytest.mark.slow  # each example script runs for minutes
def test_table1_trains_vocabularies_on_the_other_query_and_the_doc_quotes_it(table1: tuple[dict, str]) -> None:
    summary, stdout = table1
    assert {q: v["trained_on"] for q, v in summary["vocabularies"].items()} == \
        {"day_left": "night_right", "night_right": "day_left"}
    assert len(summary["table"]) == 10 and all(row["ms_per_frame"] > 0 for row in summary["table"])
    tables = _example("table1").render(summary)
    assert tables in stdout
    quoted = _protocol().block_in((REPO / "docs" / "results.md").read_text(encoding="utf-8"), "table1")
    # OpenCV's SIFT runs CPU-specific code: the local-feature rows differ between x86-64 machines
    # (docs/results.md gives both measurements); the whole-image rows must match
    assert_quotes(quoted, tables, "run examples/table1.py --update-docs",
                  cpu_dependent=("FAB-MAP", "CAT-Graph local features"))


@pytest.mark.realdata
@pytest.mark.slow  # the example runs for minutes
def test_loop_closure_runs_each_method_on_each_loop_and_the_doc_quotes_it(
        data_root: Path, tmp_path_factory: pytest.TempPathFactory, real_data_cache: Path) -> None:
    summary, stdout = _run_example("loop_closure", data_root, tmp_path_factory, real_data_cache)
    module = _example("loop_closure")
    assert {(row["label"], row["loop"]) for row in summary["table"]} == \
        {(label, loop) for label, _, _ in module.RUNS for loop in module.LOOPS}
    for row in summary["table"]:
        assert 0.0 <= row["recall@100"] <= row["recall@99"] <= 1.0
        # the vocabulary is never trained on a traversal of the loop itself
        assert row["vocabulary"] is None or row["vocabulary"] not in row["loop"].split("+")
    tables = module.render(summary)
    assert tables in stdout
    quoted = _protocol().block_in((REPO / "docs" / "results.md").read_text(encoding="utf-8"), "loop_closure")
    # FAB-MAP's local features run CPU-specific code (as in Table I), and the CAT-Graph filter over gist
    # rows (CAT-Graph's, and the online model's confidence) follows the last digits of gist, which the
    # oldest dependencies compute otherwise: only those rows' text and shape must match
    assert_quotes(quoted, tables, "run examples/loop_closure.py --update-docs",
                  cpu_dependent=("FAB-MAP", "online gist", "CAT-Graph gist"))
