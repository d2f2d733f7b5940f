"""Tables at the widths people read them: the docs' example commands at 80 columns break no name
inside a word; at 160 the Recall@N headers stay on one line; compare writes CSV, Markdown and
LaTeX."""
from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import pytest
from helpers import places, write_traversal
from typer.testing import CliRunner

from wiloc.cli import app
from wiloc.evaluation.results import read_results, write_results
from wiloc.labels import threshold_text
from wiloc.wrapping import widest_word, wrap

runner = CliRunner()
NARROW, WIDE = "80", "400"


def _words(text: str) -> set[str]:
    return set(re.findall(r"[A-Za-z][A-Za-z0-9]*", text))


def _fragments(names: list[str]) -> set[str]:
    """Every piece a word of ``names`` would leave if it broke inside: its proper prefixes and
    suffixes of two characters or more."""
    return {word[:i] for name in names for word in _words(name) for i in range(2, len(word))} | \
           {word[i:] for name in names for word in _words(name) for i in range(1, len(word) - 1)}


def _invoke(args: list[str], columns: str) -> str:
    result = runner.invoke(app, args, env={"COLUMNS": columns})
    assert result.exit_code == 0, result.output
    return result.stdout


def assert_no_word_broken(args: list[str], names: list[str]) -> str:
    """Run ``args`` at 80 columns: no word of ``names`` may be broken across lines, i.e. the
    output holds no piece of one (a prefix or suffix) that the same output at 400 columns, where
    nothing wraps, does not hold as a word of its own. Returns the narrow output."""
    narrow = _invoke(args, NARROW)
    assert max(map(len, narrow.splitlines())) <= int(NARROW), narrow
    broken = (_words(narrow) & _fragments(names)) - _words(_invoke(args, WIDE))
    assert not broken, f"{' '.join(args[:1])} broke {sorted(broken)} at {NARROW} columns:\n{narrow}"
    return narrow


def test_wrapping_breaks_only_after_separators() -> None:
    assert wrap("gardens-point-walking/day_right", 12) == ["gardens-", "point-", "walking/day_", "right"]
    assert wrap("online night_right", 12) == ["online", "night_right"]
    assert wrap("brisk-gist", 3) == ["brisk-", "gist"]  # a word wider than the column stays whole
    assert widest_word("catgraph/sad\nday_left") == len("catgraph/")


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    """Gardens Point's names on small generated traversals: day_left and night_right localized
    against day_right with online, threshold and catgraph, and the online runs again as if with
    brisk-gist (so that compare labels runs method/descriptor, catgraph/sad)."""
    tmp = tmp_path_factory.mktemp("tables")
    data, out = tmp / "gardens-point-walking", tmp / "runs"
    out.mkdir()
    scenes = places(24)
    for name, gain, seed in (("day_right", 1.0, 1), ("day_left", 0.8, 2), ("night_right", 0.6, 3)):
        write_traversal(data / name, scenes, gain, seed)
    env = {"WILOC_CACHE": str(tmp / "cache")}
    for method in ("online", "threshold", "catgraph"):
        result = runner.invoke(app, ["localize", str(data / "day_left"), str(data / "night_right"), "--map",
                                     str(data / "day_right"), "--method", method, "--out", str(out), "--jobs", "1"],
                               env=env)
        assert result.exit_code == 0, result.output
    for query in ("day_left", "night_right"):
        results = read_results(out / f"{query}-sad-online.csv")
        write_results(out / f"{query}-brisk-gist-online.csv",
                      replace(results, header=replace(results.header, descriptor="brisk-gist")))
    names = [str(data / "day_right"), "catgraph/sad", "online/brisk-gist", "threshold/sad",
             *(path.name for path in out.glob("*.csv"))]
    return tmp, names


def test_the_docs_examples_break_no_name_at_80_columns(runs: tuple[Path, list[str]],
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    tmp, names = runs
    monkeypatch.setenv("WILOC_CACHE", str(tmp / "cache"))
    data, out = tmp / "gardens-point-walking", tmp / "runs"
    everything = sorted(map(str, out.glob("*.csv")))
    describe = assert_no_word_broken(["describe", *(str(data / n) for n in ("day_right", "day_left", "night_right")),
                                      "--descriptor", "sad", "--jobs", "1"], names)
    assert "night_right" in describe and "[24, 1152]" not in describe
    compare = assert_no_word_broken(["compare", *everything, "--gt", "aligned", "--tolerance", "2",
                                     "--recall-at", "1,5,10,20"], names)
    assert "catgraph/sad" in compare and "online/brisk-gist" in compare
    assert_no_word_broken(["evaluate", *everything, "--gt", "aligned", "--tolerance", "2"], names)
    assert_no_word_broken(["evaluate", str(out / "day_left-sad-online.csv"), str(out / "night_right-sad-catgraph.csv")],
                          names)
    assert_no_word_broken(["localize", str(data / "day_left"), str(data / "night_right"), "--map",
                           str(data / "day_right"), "--method", "threshold", "--out", str(tmp / "again")], names)
    assert_no_word_broken(["vocabulary", str(data / "night_right"), "--words", "4", "--max-side", "96"], names)


def test_recall_at_n_headers_stay_on_one_line_at_160_columns(runs: tuple[Path, list[str]]) -> None:
    tmp, _ = runs
    everything = sorted(map(str, (tmp / "runs").glob("*.csv")))
    compare = _invoke(["compare", *everything, "--recall-at", "1,5,10,20"], "160")
    assert all(len(line) <= 160 for line in compare.splitlines())
    assert re.search(r"R@1\b.*R@5\b.*R@10\b.*R@20\b", compare), compare  # one header line holds them all
    evaluate = _invoke(["evaluate", *everything, "--recall-at", "1,5,10,20"], "160")
    assert all(f"R@{n} (a true match in the {n} best)" in evaluate for n in (5, 10, 20)), evaluate


def test_compare_writes_csv_markdown_and_latex(runs: tuple[Path, list[str]]) -> None:
    tmp, _ = runs
    everything = sorted(map(str, (tmp / "runs").glob("*.csv")))
    result = runner.invoke(app, ["compare", *everything, "--csv", str(tmp / "compare.csv")])
    assert result.exit_code == 0, result.output
    import pandas as pd
    metrics = pd.read_csv(tmp / "compare.csv")
    assert len(metrics) == len(everything) and {"results", "method", "descriptor", "traversal", "recall_at_5",
                                                  "ece"} <= set(metrics.columns)
    assert set(pd.read_csv(tmp / "compare-curves.csv")["results"]) == set(everything)
    markdown = _invoke(["compare", *everything, "--markdown", "--recall-at", "1,20"], NARROW)
    table1 = [line for line in markdown.splitlines() if line.startswith("| day_left | catgraph/sad |")]
    assert markdown.count("|---|---|") == 4 and len(table1) == 3  # Table I, the calibration, P(new place)'s
    new_place = markdown.split("**P(new place) against the frames without a true match", 1)[1].split("**Table II", 1)[0]
    assert "| traversal | method | ECE | Brier | mean P(new place) | share new |" in new_place
    said = {(run["traversal"], run["label"]): run["new_place"] for run in json.loads(
        _invoke(["compare", *everything, "--json"], NARROW))["runs"] if "new_place" in run}
    rows = [line.split(" | ") for line in new_place.splitlines()[4:] if line.startswith("| ")]  # under the head
    assert said and len(rows) == len(said)  # the runs that say P(new place), with compare's numbers
    for traversal, label, ece, brier, *_ in rows:
        assert (float(ece), float(brier)) == pytest.approx(
            (said[traversal.strip("| "), label]["ece"], said[traversal.strip("| "), label]["brier"]), abs=5e-4)
    assert "| traversal | method | R@100%P | R@99%P | R@90%P | AUC | R@1 | R@20 |" in markdown
    latex = _invoke(["compare", *everything, "--latex", "--no-global-threshold"], NARROW)
    assert latex.count(r"\begin{tabular}") == 3 and r"day\_left & catgraph/sad &" in latex
    # >= and +- typeset as symbols, never as characters the default font encoding prints otherwise
    assert r"confidence $\geq$ cut" in latex and ">" not in latex.replace(r"\textgreater{}", "")
    both = runner.invoke(app, ["compare", *everything, "--markdown", "--latex"])
    assert both.exit_code == 2 and "--latex: give one of" in both.output


def _names_to_four_digits(text: str, value: float | None) -> bool:
    """Whether a printed threshold names ``value`` to four significant digits of its distance to 0
    or 1, whichever is nearer (where confidences crowd), rounded down (a cut there accepts it)."""
    if value is None:
        return text == "-"
    gap = min(abs(value), abs(1.0 - value))
    return 0.0 <= value - float(text) < (10.0 ** (math.floor(math.log10(gap)) - 3) if gap else 1e-300)


@pytest.mark.parametrize("value", [0.130062217, 0.98928, 0.9995169, 0.29, 0.0013337, 0.56789, -0.0456789, 0.5])
def test_a_threshold_taken_as_printed_as_a_cut_keeps_the_frame_that_set_it(value: float) -> None:
    """Table II's 0.130062217 was printed 0.1301, rounded to nearest: a cut there (confidence >=
    cut is accepted) loses the frame whose confidence set the threshold, and recall falls below the
    table's. Rounded down, the printed cut accepts it, and still names the value to its digits."""
    text = threshold_text(value)
    assert float(text) <= value and _names_to_four_digits(text, value), text
    if value == 0.130062217:
        assert text == "0.130"  # 0.1300: no trailing zero beyond 3 decimals


def test_thresholds_are_printed_with_the_digits_that_say_what_was_chosen(runs: tuple[Path, list[str]]) -> None:
    """Table II (as a table and in Markdown) and evaluate's threshold at max F1 showed 3 decimals:
    0.99951 as 1.000, 0.9897 and 0.9903 both as 0.990. JSON keeps the full float."""
    assert [threshold_text(v) for v in (0.99951, 0.9897, 0.9903, 0.14, 1.5e-05, 1.0, math.nan)] == [
        "0.99951", "0.9897", "0.9903", "0.140", "0.000015", "1.000", "-"]
    tmp, _ = runs
    everything = sorted(map(str, (tmp / "runs").glob("*.csv")))
    args = ["compare", *everything, "--precision", "100,99,90"]
    chosen = {(row["method"], f"{row['precision']:g}%"): row["threshold"]
              for row in json.loads(_invoke([*args, "--json"], WIDE))["table2"]}
    table = [[part.strip() for part in line.split("│")[1:4]] for line in _invoke(args, WIDE).split("Table II", 1)[1]
             .splitlines() if line.startswith("│") and "%" in line]
    markdown = [line.split(" | ")[:3] for line in _invoke([*args, "--markdown"], WIDE).split("**Table II", 1)[1]
                .splitlines() if line.startswith("| ") and "%" in line]
    for shown in (table, [[method.removeprefix("| "), target, text] for method, target, text in markdown]):
        assert {(method, target) for method, target, _ in shown} == set(chosen)  # Markdown: once per traversal
        assert all(_names_to_four_digits(text, chosen[method, target]) for method, target, text in shown), shown
    assert len(table) == len(chosen) and any(len(text.split(".")[1]) > 3 for _, _, text in table)  # 3 decimals lost
    said = json.loads(_invoke(["evaluate", *everything, "--json"], WIDE))["runs"]
    (line,) = [line for line in _invoke(["evaluate", *everything], WIDE).splitlines() if "threshold at max F1" in line]
    shown = [part.strip() for part in line.split("│")[2:-1]]
    assert len(shown) == len(said) and all(map(_names_to_four_digits, shown, [run["max_f1_threshold"] for run in said]))
