"""`wiloc compare`: methods and traversals side by side (the paper's Table I, calibration at
fixed cuts, Table II), as tables, Markdown, LaTeX or JSON, with its figures."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer

from wiloc.cli.core import Notes, fail, handles_errors, note, out, refuse_unused
from wiloc.cli.options import CalibrationPlotOption, PrPlotOption, plot_file, replacing, separate_outputs
from wiloc.cli.scoring import (CUTS_TEXT, RECALL_AT_TEXT, CutsOption, FramesOption, RecallAtOption, metrics_file,
                               metrics_outputs, parse_cuts, parse_recall_at, scored_frames, slice_columns,
                               slice_key, warn_about_truth, write_metrics_csv)
from wiloc.cli.truth import GtMapOption, GtOption, RadiusOption, ToleranceOption, truth_source
from wiloc.cli.views import (compared_runs, comparison_records, cut_views, new_place_view, print_command_json,
                             table1_view, table2_view)
from wiloc.errors import EXIT_USAGE

if TYPE_CHECKING:
    from wiloc import api


@handles_errors
def compare(
    results: list[Path] = typer.Argument(..., metavar="RESULTS...", help="Results files: several methods x query traversals."),
    gt: GtOption = "aligned",
    gt_map: GtMapOption = None,
    tolerance: ToleranceOption = 2,
    radius: RadiusOption = None,
    global_threshold: bool = typer.Option(True, "--global-threshold/--no-global-threshold",
                                          help="Table II: one threshold per method for all traversals."),
    precision: str = typer.Option("100,99", help="Table II target precisions in percent, comma-separated."),
    cuts: CutsOption = CUTS_TEXT,
    recall_at: RecallAtOption = RECALL_AT_TEXT,
    frames: FramesOption = None,
    threshold_plot: Optional[Path] = typer.Option(None, callback=plot_file, show_default="none: not drawn", help="Precision against normalised threshold (the paper's Figure 5)."),
    model_plot: Optional[Path] = typer.Option(None, callback=plot_file, show_default="none: not drawn", help="Learned histograms of the first online run, else of the first trained one (Figure 1)."),
    pr_plot: PrPlotOption = None,
    calibration_plot: CalibrationPlotOption = None,
    csv_out: Optional[Path] = typer.Option(None, "--csv", callback=metrics_file, show_default="none: not written",
                                           help="Write each run's metrics as CSV, and the curves to FILE-curves.csv beside it."),
    markdown: bool = typer.Option(False, "--markdown", help="Print the tables as Markdown instead."),
    latex: bool = typer.Option(False, "--latex", help="Print the tables as LaTeX (booktabs) instead."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Methods and traversals side by side: the paper's Table I, calibration at fixed cuts, Table II.

    Example: wiloc compare *-online.csv *-threshold.csv --gt aligned -T 2 --precision 100,99
    """
    from wiloc import api

    refuse_unused({"precision": (global_threshold, "Table II (--global-threshold)")})
    separate_outputs(results, {"--threshold-plot": threshold_plot, "--model-plot": model_plot, "--pr-plot": pr_plot,
                               "--calibration-plot": calibration_plot, "--csv": metrics_outputs(csv_out)})
    shown = [flag for flag, given in (("--markdown", markdown), ("--latex", latex), ("--json", as_json)) if given]
    if len(shown) > 1:
        fail(f"{shown[1]}: give one of --markdown, --latex and --json", EXIT_USAGE)
    try:
        targets = list(dict.fromkeys(float(p) for p in precision.split(",") if p.strip()))  # each once, as given
    except ValueError:
        fail(f"--precision: '{precision}': give percentages such as 100,99.5", EXIT_USAGE)
    at = parse_cuts(cuts)
    ranks = parse_recall_at(recall_at)
    source = truth_source(gt, gt_map, tolerance, radius)
    comparison = api.compare(results, source, precisions=targets, global_thresholds=global_threshold, cuts=at,
                             recall_at=ranks, frames=frames)
    notes = warn_about_truth(comparison.evaluations)
    written = _compare_plots(comparison, source, threshold_plot, model_plot, pr_plot, calibration_plot, notes)
    records = comparison_records(comparison)
    if csv_out is not None:
        (_, table1, _, _), (_, calibration, _, _) = records[:2]
        runs = [{"results": str(e.path), "descriptor": e.results.header.descriptor, **a, **b, **slice_columns(e)}
                for e, a, b in zip(comparison.evaluations, table1, calibration)]
        written += write_metrics_csv(csv_out, runs, comparison.evaluations, notes)
    if markdown or latex:
        from wiloc.text_tables import latex as as_latex
        from wiloc.text_tables import markdown as as_markdown
        for title, rows, columns, labels in records if global_threshold else records[:-1]:  # Table II is last
            print(as_latex(rows, columns, labels, title) if latex else f"**{title}**\n\n{as_markdown(rows, columns, labels)}",
                  end="\n\n")
        for line in scored_frames(comparison.evaluations):
            note("scored", line)
        for path in written:
            note("wrote", str(path))  # stdout holds the tables alone
        return
    if as_json:
        print_command_json("compare", "runs", compared_runs(comparison), notes, ground_truth=comparison.ground_truth,
                           table2=comparison.table2.to_dict(orient="records"),
                           files=[str(p.resolve()) for p in written], **slice_key(comparison.evaluations))
        return
    out.print(table1_view(comparison))
    for view in cut_views(comparison, at):
        out.print(view)
    if (view := new_place_view(comparison.cut_table.to_dict(orient="records"), at, comparison.ground_truth,
                               ["method", "traversal"])) is not None:
        out.print(view)
    if global_threshold:
        out.print(table2_view(comparison))
    for line in scored_frames(comparison.evaluations):
        out.print(line, markup=False, highlight=False)
    for path in written:
        out.print(f"wrote {path}")


def _compare_plots(comparison: api.Comparison, source: api.TruthSource, threshold_plot: Path | None,
                   model_plot: Path | None, pr_plot: Path | None, calibration_plot: Path | None,
                   notes: Notes) -> list[Path]:
    from wiloc import api
    from wiloc.figures import plots

    subject = api.run_subject(comparison.evaluations, source)
    learned = sorted((e for e in comparison.evaluations  # a file without its model line has none to draw
                      if e.method in ("online", "trained") and e.results.model is not None),
                     key=lambda e: e.method != "online")
    if model_plot is not None and not learned:  # refused before any figure is written
        fail("--model-plot: applies to online and trained runs with a model; none of the results is one",
             EXIT_USAGE)
    written = []
    if threshold_plot is not None:
        written.append(plots.plot_threshold(api.threshold_series(comparison), replacing(notes, threshold_plot),
                                            marks=api.threshold_marks(comparison),
                                            title=f"Precision against threshold: {subject}"))
    if model_plot is not None:
        run = learned[0]  # no ground truth enters the model's title
        written.append(plots.plot_model(run.results.model, replacing(notes, model_plot),
                                        title=f"Learned model: {run.method}, {run.traversal} "
                                              f"({api.run_subject([run], None)})"))
    if pr_plot is not None:
        written.append(plots.plot_pr(api.pr_series(comparison), replacing(notes, pr_plot),
                                     title=f"Precision-recall: {subject}"))
    if calibration_plot is not None:
        written.append(plots.plot_reliability(api.reliability_series(comparison.evaluations),
                                              replacing(notes, calibration_plot), title=f"Reliability: {subject}",
                                              new_place=api.new_place_series(comparison.evaluations)))
    return written
