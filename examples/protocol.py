"""The paper's evaluation protocol on a real dataset, shared by the example scripts.

For every descriptor, method and query traversal: ``wiloc.api.localize`` against the map; then
``wiloc.api.compare`` (Table I and Table II), the plots (Figure 5 precision against threshold,
Figure 1 learned histograms, precision-recall curves), and ``summary.json`` with the table rows.
``render_markdown`` turns a summary into the tables of docs/results.md, between the markers of
``doc_block``; ``--update-docs`` rewrites that block and the plots under docs/img/, and
tests/test_examples.py regenerates the tables and compares them with the block.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from wiloc import api
from wiloc.atomic import write_error
from wiloc.cache.store import Cache
from wiloc.cli.core import error, note, out as console  # wiloc's: a path holding ':name:' is printed as typed
from wiloc.cli.views import progress_bar, table1_view, table2_view
from wiloc.descriptors.registry import DESCRIPTOR_NAMES, descriptor_class
from wiloc.errors import EXIT_INTERRUPTED, EXIT_USAGE, UsageError, WilocError, interrupted
from wiloc.figures import plots, run_figures
from wiloc.labels import threshold_text

if TYPE_CHECKING:
    from wiloc.description.vocabulary_build import VocabularyReport

REPO = Path(__file__).resolve().parents[1]
METHODS = ("online", "threshold", "trained", "catgraph")
RECALL_AT = (1, 5, 10, 20)  # Recall@N as place recognition papers report it
TABLE_OUTPUTS = ("summary.json", "pr.png", "results")  # what a one-table example writes into --out
_said_skipped: set[tuple[str, str]] = set()  # the frames left out that were said (:func:`say_skipped`)


@dataclass(frozen=True)
class Experiment:
    """One protocol run: a map, its query traversals, descriptors, and how ``trained`` is trained."""

    name: str
    reference: Path
    queries: list[Path]
    descriptors: list[str]
    training: Callable[[Path], api.Training]  # the labelled pair used when testing one query
    training_note: str
    tolerance: int


def default_data_root() -> Path:
    """$WILOC_DATA, else the shared data folder beside the repository."""
    return Path(os.environ.get("WILOC_DATA") or REPO.parent / "shared" / "data")


class _Parser(argparse.ArgumentParser):
    """argparse ending on a usage problem as the wiloc command does: one line naming the option as
    typed and exit code 2, not argparse's usage lines."""

    def error(self, message: str) -> NoReturn:
        unknown = message.removeprefix("unrecognized arguments: ")
        if unknown != message:
            first = unknown.split()[0]
            surplus = "no such option" if first.startswith("-") else "an argument too many"
            message = f"{first}: {surplus} of {self.prog} (see --help)"
        error(message.removeprefix("argument "))
        sys.exit(EXIT_USAGE)


def common_parser(name: str, description: str) -> argparse.ArgumentParser:
    """A parser of the options every example takes, the data folder and the output folder, that
    ends on a usage problem in one line (exit code 2) as the wiloc command does."""
    parser = _Parser(description=description)
    parser.add_argument("data", nargs="?", type=Path, default=default_data_root(),
                        help="folder holding the datasets (default: $WILOC_DATA or ../shared/data)")
    parser.add_argument("--out", type=Path, default=Path("wiloc-examples") / name,
                        help="output folder (default: %(default)s)")
    return parser


def parse_args(name: str, description: str, descriptors: bool) -> argparse.Namespace:
    """The examples' common options (:func:`common_parser`), --update-docs and (maybe)
    descriptors, each descriptor checked before any work (a UsageError naming --descriptors)."""
    parser = common_parser(name, description)
    parser.add_argument("--update-docs", action="store_true",
                        help="rewrite this example's tables in docs/results.md and its plots in docs/img/")
    if descriptors:
        parser.add_argument("--descriptors", default="sad",
                            help="comma-separated: sad, gist, brisk-gist (default: %(default)s)")
    args = parser.parse_args()
    if descriptors:
        check_descriptors(args.descriptors)
    return args


def check_descriptors(text: str) -> None:
    """--descriptors as typed: at least one name, each a descriptor that needs no file (the
    examples give none); a UsageError naming --descriptors otherwise, before anything is made."""
    names = [d.strip() for d in text.split(",") if d.strip()]
    if not names:
        raise UsageError("--descriptors", f"no descriptor in {text!r}; give names such as sad,gist")
    for descriptor in names:
        try:
            needs = descriptor_class(descriptor).depends
        except ValueError as exc:
            raise UsageError("--descriptors", str(exc)) from None
        if needs:
            raise UsageError("--descriptors", f"'{descriptor}' depends on {needs}, which the examples do not take; "
                                              f"give {', '.join(DESCRIPTOR_NAMES)} or a plugin's")


def aligned(tolerance: int) -> api.TruthSource:
    """Aligned ground truth: the same file name is the same place, +-tolerance frames."""
    return api.TruthSource(kind="aligned", tolerance=tolerance)


def say_skipped(frames: Iterable[tuple[str, str]]) -> None:
    """``skipped PATH: why`` on stderr for each frame the library left out, as `wiloc localize`
    says it: once a frame, however many runs leave it out."""
    for path, reason in frames:
        if (path, reason) not in _said_skipped:
            note("skipped", f"{path}: {reason}")
            _said_skipped.add((path, reason))


def localize(query: Path, **options: Any) -> api.LocalizeRun:
    """``wiloc.api.localize``, saying the frames it left out (:func:`say_skipped`)."""
    run = api.localize(query, **options)
    say_skipped(run.skipped)
    return run


def vocabulary(folders: Sequence[Path]) -> VocabularyReport:
    """``wiloc.api.vocabulary``, saying the training frames it left out (:func:`say_skipped`)."""
    report = api.vocabulary(folders)
    say_skipped(report.failed)
    return report


def say_written(paths: Iterable[Path]) -> None:
    """``wrote PATH`` for each output, never folded: where an example's outputs went."""
    for path in paths:
        print(f"wrote {path}", flush=True)


def run_experiment(experiment: Experiment, out: Path) -> dict[str, Any]:
    """Localize every query with every method and descriptor, compare, plot, write summary.json."""
    output_folder(out)
    paths = []
    with progress_bar(True) as progress:
        for descriptor in experiment.descriptors:
            for method in METHODS:
                for query in experiment.queries:
                    run = localize(
                        query, reference=experiment.reference, descriptor=descriptor, method=method,
                        training=experiment.training(query) if method == "trained" else None,
                        out=out / "results" / f"{query.name}-{descriptor}-{method}.csv", progress=progress)
                    paths.append(run.path)
    comparison = api.compare(paths, aligned(experiment.tolerance), recall_at=RECALL_AT)
    online = next(e for e in comparison.evaluations if e.method == "online")
    files = [plots.plot_threshold(api.threshold_series(comparison), out / "threshold.png",
                                  title=f"{experiment.name}: precision against threshold"),
             plots.plot_model(online.results.model, out / "model.png",
                              title=f"{experiment.name}: online model learned on {online.traversal}"),
             plots.plot_pr(api.pr_series(comparison), out / "pr.png",
                           title=f"{experiment.name}: precision-recall"),
             plots.plot_reliability(api.reliability_series(comparison.evaluations), out / "reliability.png",
                                    title=f"{experiment.name}: reliability of the confidences"),
             *run_plots(next(e for e in reversed(comparison.evaluations) if e.method == "catgraph"), out,
                        experiment.name)]
    summary = _finite({"experiment": experiment.name, "map": experiment.reference.name,
               "queries": [q.name for q in experiment.queries], "descriptors": experiment.descriptors,
               "ground_truth": f"aligned, +-{experiment.tolerance} frames",
               "trained_on": experiment.training_note,
               "table1": comparison.table1.to_dict(orient="records"),
               "table2": comparison.table2.to_dict(orient="records"),
               "calibration": comparison.cut_table.to_dict(orient="records")})
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    console.print(table1_view(comparison))
    console.print(table2_view(comparison))
    console.print(f"trained: {experiment.training_note}")
    print(render_markdown(summary))
    say_written([out / "summary.json", *files, out / "results"])
    return summary


def run_plots(evaluation: api.Evaluation, out: Path, name: str) -> list[Path]:
    """One run's difference matrix (decided matches and ground truth over it) and its most
    confident right and wrong matches as image pairs."""
    picture = run_figures.matrix_picture(evaluation, Cache())
    return [plots.plot_matrix(picture, out / "matrix.png", title=(
                f"{name}: {evaluation.method} on {picture.query} against {picture.reference}, differences, "
                "decided matches and ground truth")),
            plots.plot_pairs(run_figures.example_pairs(evaluation), out / "pairs.png", title=(
                f"{name}: {evaluation.method} on {evaluation.traversal}, the most confident right and wrong matches"))]


def _finite(value: Any) -> Any:
    """JSON-ready: NaN and infinities become null, numpy scalars plain numbers."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    if hasattr(value, "item"):
        value = value.item()
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f}"


def render_markdown(summary: dict[str, Any]) -> str:
    """Table I and Table II of a summary as the markdown pasted in docs/results.md; Table II's
    thresholds as the CLI's tables print them (:func:`wiloc.labels.threshold_text`: rounded down,
    so that one taken as a cut keeps the frame that set it)."""
    lines = ["| method | traversal | recall @100 % | @99 % | @90 % | AUC | R@1 | R@5 | R@10 | R@20 | frames |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for row in summary["table1"]:
        auc = "-" if row["auc"] is None else f"{row['auc']:.3f}"
        lines.append(f"| {row['method']} | {row['traversal']} | {_percent(row['recall_at_100'])} | "
                     f"{_percent(row['recall_at_99'])} | {_percent(row['recall_at_90'])} | {auc} | "
                     f"{_percent(row['recall_at_1'])} | {_percent(row.get('recall_at_5'))} | "
                     f"{_percent(row.get('recall_at_10'))} | {_percent(row.get('recall_at_20'))} | {row['frames']} |")
    lines += ["", "| method | precision | global threshold | traversal | recall | worst |",
              "|---|---:|---:|---|---:|:---:|"]
    for row in summary["table2"]:
        lines.append(f"| {row['method']} | {row['precision']:g} % | {threshold_text(row['threshold'])} | "
                     f"{row['traversal']} | {_percent(row['recall'])} | {'*' if row['worst'] else ''} |")
    lines += ["", "| method | traversal | ECE | Brier | mean confidence | share correct | "
                  "P / R at 0.5 | at 0.9 | at 0.99 |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for row in summary["calibration"]:
        at = [f"{_fraction(row[f'precision@{cut:g}'])} / {_fraction(row[f'recall@{cut:g}'])}"
              for cut in (0.5, 0.9, 0.99)]
        lines.append(f"| {row['method']} | {row['traversal']} | {_fraction(row['ece'])} | {_fraction(row['brier'])} | "
                     f"{_fraction(row['mean_confidence'])} | {_fraction(row['share_correct'])} | {' | '.join(at)} |")
    return "\n".join(lines)


def _fraction(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def doc_block(name: str) -> tuple[str, str]:
    """The markers around an example's tables in docs/results.md."""
    return (f"<!-- begin {name}: generated by examples/{name}.py --update-docs -->",
            f"<!-- end {name} -->")


def block_in(text: str, name: str) -> str:
    """The tables between an example's markers in a document ('' when the markers are missing)."""
    begin, end = doc_block(name)
    start, stop = text.find(begin), text.find(end)
    return text[start + len(begin):stop].strip("\n") if 0 <= start < stop else ""


def update_docs(summary: dict[str, Any], out: Path, markdown: str | None = None,
                plots: Sequence[str] = ("threshold", "model", "pr", "reliability", "matrix", "pairs")) -> None:
    """Rewrite the example's block in docs/results.md (``markdown``, default: the protocol's
    tables) and copy its plots to docs/img/."""
    name = summary["experiment"]
    doc = REPO / "docs" / "results.md"
    text = doc.read_text(encoding="utf-8")
    begin, end = doc_block(name)
    start, stop = text.find(begin), text.find(end)
    if not 0 <= start < stop:
        raise WilocError(doc, f"no '{begin}' ... '{end}' markers to update")
    block = render_markdown(summary) if markdown is None else markdown
    doc.write_text(f"{text[:start + len(begin)]}\n{block}\n{text[stop:]}", encoding="utf-8")
    for plot in plots:
        shutil.copyfile(out / f"{plot}.png", REPO / "docs" / "img" / f"{name}-{plot}.png")
    console.print(f"updated {doc} and docs/img/{name}-*.png")


@contextmanager
def one_line_errors() -> Iterator[None]:
    """An example's end on a problem, never a traceback: bad input as one error line and its exit
    code, Ctrl-C as 'error: interrupted' and 130, as the wiloc command ends (what was described
    stays in the cache: a rerun goes on from there)."""
    try:
        yield
    except WilocError as exc:
        error(str(exc))
        sys.exit(exc.exit_code)
    except BaseException as exc:
        if not interrupted(exc):
            raise
        error("interrupted")  # puts stderr back first: a Ctrl-C may end image decoders' quiet stretch before it does
        sys.exit(EXIT_INTERRUPTED)


def main(build: Callable[[], tuple[Experiment, Path, bool]]) -> None:
    """Run an example (:func:`one_line_errors`)."""
    with one_line_errors():
        experiment, out, docs = build()
        summary = run_experiment(experiment, out)
        if docs:
            update_docs(summary, out)


def run_table_script(name: str, description: str, run: Callable[[Path, Path], dict[str, Any]],
                     render: Callable[[dict[str, Any]], str]) -> None:
    """Run an example that prints one table and draws PR curves (``run(data, out)`` gives its
    summary and writes :data:`TABLE_OUTPUTS`, ``render`` the table docs/results.md quotes;
    :func:`one_line_errors`)."""
    args = parse_args(name, description, descriptors=False)
    with one_line_errors():
        check_output_folder(args.out)
        summary = run(args.data, args.out)
        say_written(args.out / output for output in TABLE_OUTPUTS)
        if args.update_docs:
            update_docs(summary, args.out, markdown=render(summary), plots=("pr",))


def check_output_folder(folder: Path) -> None:
    """``--out`` before any work: a file there is an error naming it."""
    if folder.exists() and not folder.is_dir():
        raise WilocError(folder, "not a folder (--out names the output folder)")


def output_folder(folder: Path) -> None:
    """Make ``--out`` before any work: a file there, or a folder that cannot be made, is an error
    naming it."""
    check_output_folder(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise write_error(folder, "the output folder", exc) from None


def require(folders: Sequence[Path]) -> None:
    """Stop with a clear message when a dataset folder is missing."""
    for folder in folders:
        if not folder.is_dir():
            raise WilocError(folder, "dataset folder not found (pass the data folder or set WILOC_DATA)")
