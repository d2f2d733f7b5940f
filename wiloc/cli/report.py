"""`wiloc report`: one self-contained HTML page of a comparison."""
from __future__ import annotations

from pathlib import Path

import typer

from wiloc.cli.core import handles_errors, out
from wiloc.cli.options import CacheOption, one_file, replacing
from wiloc.cli.scoring import (CUTS_TEXT, CutsOption, FramesOption, parse_cuts, scored_frames, slice_key,
                               warn_about_truth)
from wiloc.cli.truth import GtMapOption, GtOption, RadiusOption, ToleranceOption, truth_source
from wiloc.cli.views import print_command_json, progress_bar


def _html_file(value: Path) -> Path:
    """The report's file: its folder must exist, nothing but a file be there, its name end in .html or .htm."""
    one_file(value)
    if value.suffix.lower() not in (".html", ".htm"):
        raise typer.BadParameter(f"'{value}': the report is an HTML page; end the name in .html or .htm")
    return value


@handles_errors
def report(
    results: list[Path] = typer.Argument(..., metavar="RESULTS...", help="Results files: several methods x query traversals."),
    out_file: Path = typer.Option(Path("report.html"), "--out", "-o", callback=_html_file,
                                  help="The HTML page to write."),
    gt: GtOption = "aligned",
    gt_map: GtMapOption = None,
    tolerance: ToleranceOption = 2,
    radius: RadiusOption = None,
    cuts: CutsOption = CUTS_TEXT,
    frames: FramesOption = None,
    thumb_width: int = typer.Option(160, min=40, max=640, help="Width in pixels of the frame browser's images."),
    cache: CacheOption = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a line."),
) -> None:
    """One self-contained HTML page of a comparison: tables, figures, timelines and a frame browser.

    Per run a timeline and the difference matrix; the page needs no network, images are embedded as thumbnails.

    With --frames the tables, figures and browser cover that slice of each run's frames; the matrices are left out.

    Example: wiloc report runs/day_left-sad-online.csv runs/day_left-sad-catgraph.csv --gt aligned -o report.html
    """
    from wiloc import api
    from wiloc.cache.store import Cache
    from wiloc.figures.report import write_report

    at = parse_cuts(cuts)
    source = truth_source(gt, gt_map, tolerance, radius)
    comparison = api.compare(results, source, cuts=at, frames=frames)
    notes = warn_about_truth(comparison.evaluations)
    with progress_bar(not as_json) as progress:
        written = write_report(comparison, replacing(notes, out_file), cache=Cache(cache), thumb_width=thumb_width,
                               title=f"wiloc report: {api.run_subject(comparison.evaluations, source)}",
                               scope=scored_frames(comparison.evaluations), progress=progress)
    for note in written.notes:
        notes.add("note", note)
    if as_json:
        print_command_json("report", "results", [{"file": str(written.path.resolve()), "size": written.size,
                                                  "images": written.images, "thumb_width": written.thumb_width}],
                           notes, **slice_key(comparison.evaluations))
        return
    for line in scored_frames(comparison.evaluations):
        out.print(line, markup=False, highlight=False)
    out.print(f"wrote {written.path} ({written.size / 1e6:.1f} MB, {written.images} images "
              f"at most {written.thumb_width} px wide)")
