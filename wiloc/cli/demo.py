"""`wiloc demo`: a generated route localized by online, threshold and catgraph and compared."""
from __future__ import annotations

import os
from pathlib import Path

import typer

from wiloc.atomic import name_problem
from wiloc.cli.core import Notes, handles_errors, out
from wiloc.cli.views import compared_runs, print_command_json, progress_bar, table1_view, table2_view


def output_folder(value: Path) -> Path:
    """``--out``, checked as the options are read, before any work: a folder (made if missing),
    so neither it nor a folder above it may be a file, and not ``-`` (no name for standard output
    here)."""
    if str(value) == "-":
        raise typer.BadParameter("-: wiloc writes a folder of files here, not standard output (give a folder)")
    if (problem := name_problem(value)) is not None:
        raise typer.BadParameter(f"{value}: {problem}")
    existing = next(path for path in (value, *value.parents) if path.exists())
    if not existing.is_dir():
        raise typer.BadParameter(f"{existing} is a file, not a folder")
    return value


@handles_errors
def demo(
    out_dir: Path = typer.Option(Path("wiloc-demo"), "--out", callback=output_folder,
                                 help="Where the demo route, results and plots go (a folder, made if missing)."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Generate a small route with ground truth, localize it with online, threshold and catgraph, compare them.

    Example: wiloc demo --out /tmp/wiloc-demo
    """
    from wiloc.demo import run_demo
    before = {path.resolve() for path in out_dir.rglob("*")} if out_dir.is_dir() else set()
    with progress_bar(not as_json) as progress:
        report = run_demo(out_dir, progress=progress)
    notes = Notes()
    for path in report.files:
        if path.resolve() in before:
            notes.add("note", f"replaced the existing file {path}")
    if as_json:
        print_command_json("demo", "runs", compared_runs(report.comparison), notes,
                           ground_truth=report.comparison.ground_truth,
                           table2=report.comparison.table2.to_dict(orient="records"), out=str(out_dir.resolve()),
                           files=[str(p.resolve()) for p in report.files])
        return
    out.print(table1_view(report.comparison))
    out.print(table2_view(report.comparison))
    out.print(f"demo outputs in [bold]{out_dir}[/bold]: " + ", ".join(os.path.relpath(p, out_dir) for p in report.files))
