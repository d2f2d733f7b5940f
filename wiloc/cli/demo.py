"""`wiloc demo`: a generated route localized by every method and compared."""
from __future__ import annotations

from pathlib import Path

import typer

from wiloc.cli.core import handles_errors, out
from wiloc.cli.views import print_command_json, progress_bar, run_records, table1_view, table2_view


@handles_errors
def demo(
    out_dir: Path = typer.Option(Path("wiloc-demo"), "--out", help="Where the demo route, results and plots go."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Generate a small route with ground truth, localize it with every method and compare them.

    Example: wiloc demo --out /tmp/wiloc-demo
    """
    from wiloc.demo import run_demo
    with progress_bar(not as_json) as progress:
        report = run_demo(out_dir, progress=progress)
    if as_json:
        print_command_json("demo", "runs", run_records(report.comparison), [],
                           table2=report.comparison.table2.to_dict(orient="records"), out=str(out_dir),
                           files=[str(p) for p in report.files])
        return
    out.print(table1_view(report.comparison))
    out.print(table2_view(report.comparison))
    out.print(f"demo outputs in [bold]{out_dir}[/bold]: " + ", ".join(p.name for p in report.files))
