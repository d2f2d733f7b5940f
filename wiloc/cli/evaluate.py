"""`wiloc evaluate`: precision-recall and calibration of results files against ground truth, one
row per run, with its figures (curves, reliability diagram, difference matrix, image pairs)."""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

import typer

from wiloc.cli.core import Notes, handles_errors, out, refuse_unused
from wiloc.cli.options import CacheOption, CalibrationPlotOption, PrPlotOption, plot_file, replacing, separate_outputs
from wiloc.cli.scoring import (CUTS_TEXT, RECALL_AT_TEXT, CutsOption, FramesOption, RecallAtOption, metrics_file,
                               metrics_outputs, parse_cuts, parse_recall_at, scored_frames, slice_columns,
                               slice_key, warn_about_truth, write_metrics_csv)
from wiloc.cli.truth import GtMapOption, GtOption, RadiusOption, ToleranceOption, truth_source
from wiloc.cli.views import metrics_views, print_command_json
from wiloc.figures.run_figures import MAX_PAIRS
from wiloc.labels import short_names

if TYPE_CHECKING:
    from wiloc import api


@handles_errors
def evaluate(
    results: list[Path] = typer.Argument(..., metavar="RESULTS...", help="Results files written by `wiloc localize`."),
    gt: GtOption = "aligned",
    gt_map: GtMapOption = None,
    tolerance: ToleranceOption = 2,
    radius: RadiusOption = None,
    pr_plot: PrPlotOption = None,
    calibration_plot: CalibrationPlotOption = None,
    cuts: CutsOption = CUTS_TEXT,
    recall_at: RecallAtOption = RECALL_AT_TEXT,
    frames: FramesOption = None,
    matrix_plot: Optional[Path] = typer.Option(
        None, callback=plot_file, show_default="none: not drawn", help="Draw the difference matrix with the decided matches and the ground truth "
                                        "(with several results files: one FILE-RESULTS figure each; of a whole run, "
                                        "not with --frames)."),
    pairs_plot: Optional[Path] = typer.Option(
        None, callback=plot_file, show_default="none: not drawn", help="Show the most confident right and wrong matches as image pairs (image "
                                        "folders; with several results files: one FILE-RESULTS figure each; with "
                                        "--frames, of those frames)."),
    pairs: int = typer.Option(3, "--pairs", min=1, max=MAX_PAIRS, help="With --pairs-plot: show N right and N wrong matches."),
    wrong_only: bool = typer.Option(False, "--wrong-only", help="With --pairs-plot: show the wrong matches only."),
    csv_out: Optional[Path] = typer.Option(None, "--csv", callback=metrics_file, show_default="none: not written", help="Write metrics as CSV, and the curves to FILE-curves.csv beside it."),
    cache: CacheOption = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Precision-recall and calibration of results files against ground truth.

    Example: wiloc evaluate day_left-sad-online.csv --gt aligned --tolerance 2 --pr-plot pr.png --cuts 0.9,0.99
    """
    from wiloc import api

    refuse_unused({"pairs": (pairs_plot is not None, "--pairs-plot"), "wrong_only": (pairs_plot is not None, "--pairs-plot"),
                   "matrix_plot": (frames is None, "a whole run (without --frames)")})
    api.check_once(results)  # each run counts once, as in compare and report
    names = short_names(results)
    matrix_files, pairs_files = _per_run(matrix_plot, names), _per_run(pairs_plot, names)
    separate_outputs(results, {"--pr-plot": pr_plot, "--calibration-plot": calibration_plot, "--matrix-plot": matrix_files,
                               "--pairs-plot": pairs_files, "--csv": metrics_outputs(csv_out)})
    at = parse_cuts(cuts)
    ranks = parse_recall_at(recall_at)
    source = truth_source(gt, gt_map, tolerance, radius)
    evaluations = [api.evaluate(path, source, at, ranks, frames=frames) for path in results]
    notes = warn_about_truth(evaluations)
    heads = [{"run": run, "results": name, "method": e.method, "descriptor": e.results.header.descriptor,
              "traversal": run.traversal, **e.summary.as_dict(), **slice_columns(e)}  # as compare labels it
             for run, name, e in zip(api.run_names(evaluations), names, evaluations)]
    rows = [{**head, **e.calibration_row()} for head, e in zip(heads, evaluations)]
    drawings = _run_plots(evaluations, matrix_files, pairs_files, cache, notes, pairs, wrong_only,
                          truth=source.describe())
    written = []
    subject = api.run_subject(evaluations, source)
    if pr_plot is not None:
        from wiloc.figures.plots import plot_pr
        written.append(plot_pr(dict(zip(api.run_names(evaluations), (e.curve for e in evaluations))),
                               replacing(notes, pr_plot), title=f"Precision-recall: {subject}"))
    if calibration_plot is not None:
        from wiloc.figures.plots import plot_reliability
        written.append(plot_reliability(api.reliability_series(evaluations), replacing(notes, calibration_plot),
                                        title=f"Reliability: {subject}", new_place=api.new_place_series(evaluations)))
    written += [draw() for draw in drawings]
    if csv_out is not None:
        written += write_metrics_csv(csv_out, rows, evaluations, notes)
    if as_json:
        print_command_json("evaluate", "runs", [
            {**head, "results": str(e.path.resolve()), "ground_truth": source.describe(), **e.calibration_dict(),
             "truth_warnings": e.truth.warnings,
             "curve": {"precision": e.curve.precision.tolist(), "recall": e.curve.recall.tolist(),
                       "thresholds": e.curve.thresholds.tolist()}} for head, e in zip(heads, evaluations)],
            notes, ground_truth=source.describe(), files=[str(p.resolve()) for p in written],
            **slice_key(evaluations))
        return
    for view in metrics_views(rows, at, source.describe()):
        out.print(view)
    for line in scored_frames(evaluations):
        out.print(line, markup=False, highlight=False)
    for path in written:
        out.print(f"wrote {path}")


def _per_run(path: Path | None, names: list[str]) -> list[Path]:
    """The files of a figure drawn per run (none when ``path`` is None): ``path`` for one run; with
    several, each named after its results file too (``names``: as many of its folders as tell
    files of one name apart, ``matrix-day_left-sad-online.png``, ``matrix-a-day_left-sad-online.png``)."""
    if path is None or len(names) == 1:
        return [] if path is None else [path]
    runs = [Path(name).with_suffix("").as_posix().replace("/", "-") for name in names]
    return [path.with_name(f"{path.stem}-{run}{path.suffix}") for run in runs]


def _run_plots(evaluations: list[api.Evaluation], matrix_files: list[Path], pairs_files: list[Path],
               cache: Path | None, notes: Notes, pairs: int = 3, wrong_only: bool = False,
               truth: str = "") -> list[Callable[[], Path]]:
    """Each run's difference matrix and example pairs (``pairs`` right and wrong ones, or wrong
    ones only) into its file of ``matrix_files`` and ``pairs_files`` (:func:`_per_run`; empty: not
    drawn), titled with the descriptor and ``truth`` (the ground truth in words), ready to be
    written: the pictures are made (and a run whose images are no longer its own refused) before
    any file is written, so a refusal leaves no output behind. A run that recorded no digest of
    its images (so that they cannot be checked as the run's) is said so."""
    if not matrix_files and not pairs_files:
        return []
    from wiloc.cache.store import Cache
    from wiloc.figures.plots import plot_matrix, plot_pairs
    from wiloc.figures.run_figures import example_pairs, matrix_picture, unchecked_folders

    store = Cache(cache)
    drawings: list[Callable[[], Path]] = []
    for i, e in enumerate(evaluations):
        subject = ", ".join(filter(None, (e.results.header.descriptor, truth)))  # right and wrong are the truth's
        for line in unchecked_folders(e):
            notes.add("warning", line)
        if matrix_files:
            picture = matrix_picture(e, store)
            title = (f"{e.method} on {picture.query} against {picture.reference} ({subject}): differences, "
                     "decided matches and ground truth")
            drawings.append(_drawing(plot_matrix, picture, matrix_files[i], title, notes))
        if pairs_files:
            shown = "wrong matches" if wrong_only else "right and wrong matches"
            of_frames = "" if e.frame_slice is None else f" of frames {e.frame_slice}"
            title = f"{e.method} on {e.traversal} ({subject}): the most confident {shown}{of_frames}"
            drawings.append(_drawing(plot_pairs, example_pairs(e, pairs, wrong_only, cache=store),
                                     pairs_files[i], title, notes))
    return drawings


def _drawing(plot: Callable[..., Path], data: Any, path: Path, title: str, notes: Notes) -> Callable[[], Path]:
    """Writing one figure made already: ``plot(data, path, title=title)``, a file replaced said so."""
    return lambda: plot(data, replacing(notes, path), title=title)
