"""How `wiloc localize` shows its runs: one row per run with the notes, skipped frames and
warnings each adds (said once), and a followed run as it goes (a live table on a terminal, else
one line or JSON line per frame)."""
from __future__ import annotations

import contextlib
import json
import statistics
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from rich.table import Table

from wiloc.cli.core import Notes, absolute_frame, out, print_line
from wiloc.cli.options import replacing
from wiloc.cli.views import cell, fit, json_ready, print_command_json, table
from wiloc.labels import short_names

if TYPE_CHECKING:
    from wiloc import api


def show_runs(runs: list[api.LocalizeRun], repairs: list[list[str]], method: str, model_plot: Path | None,
              as_json: bool, cautions: Sequence[str] = ()) -> None:
    """The runs of one `localize` as a table (or JSON), each with its cache repairs (``repairs``)
    and its notes, skipped frames and warnings, each said once; with ``model_plot``, the run's
    learned histograms drawn there (the command line gives it one run then); ``cautions``, the
    warnings said before the runs, lead the --json warnings. With --json, skipped frames are
    named by their absolute paths (:func:`absolute_frame`), on stderr too."""
    from wiloc.localization.run_files import named_path

    shown = set()
    rows, notes = [], []
    for label, run, repaired in zip(short_names([named_path(r.query) for r in runs]), runs, repairs):
        said = Notes()
        for line in (*repaired, *(line for line in run.notes if ("note", line) not in shown)):
            said.add("note", line)
            shown.add(("note", line))
        for path, reason in run.skipped:
            if (path, reason) not in shown:
                said.add("skipped", f"{absolute_frame(path) if as_json else path}: {reason}")
            shown.add((path, reason))
        if run.replaced:
            said.add("note", f"replaced the existing results file {run.path}")
        for line in run.warnings:
            if ("warning", line) not in shown:
                said.add("warning", line)
            shown.add(("warning", line))
        notes.append(said)
        d = run.decisions
        conf = d.confidence[d.decided]
        rows.append({"query": label, "method": run.method, "frames": len(d), "decided": int(d.decided.sum()),
                     "median_confidence": float(statistics.median(conf)) if len(conf) else float("nan"),
                     "seconds": run.seconds, "results": run.path.name})
    if model_plot is not None:
        from wiloc.figures.plots import plot_model
        plot_model(runs[0].decisions.model, replacing(notes[0], model_plot),
                   title=f"{named_path(runs[0].query).name} ({method})")
    if as_json:
        print_command_json("localize", "runs", [
            {**row, "descriptor": run.results.header.descriptor, "traversal": row["query"],
             "query": str(run.query.resolve()), "results": str(run.path.resolve()),
             "skipped": [[absolute_frame(path), reason] for path, reason in run.skipped]}
            for row, run in zip(rows, runs)],
            [*cautions, *(line for said in notes for line in said)])
        return
    for row in rows:
        row["decided"] = f"{row['decided']}/{row.pop('frames')}"
    folders = ", ".join(dict.fromkeys(str(run.path.absolute().parent) for run in runs))  # --out seq.csv: not "."
    out.print(table("localize", rows, ["query", "method", "decided", "median_confidence", "results"],
                    labels={"median_confidence": "median\nconf."}))
    print_line(f"results in {folders}; {sum(run.seconds for run in runs):.1f} s")
    if model_plot is not None:
        out.print(f"wrote {model_plot}")


FOLLOW_COLUMNS = ("frame", "match", "confidence", "P(new place)", "stage")


def show_followed(query: Path, run: api.FollowRun, as_json: bool) -> None:
    """Render a followed run: a live table on a terminal, else a header line and one line (or
    JSON line) per frame, and when ``--idle`` ends the run a last line saying so; a frame left out
    (or a decided file written again: a warning) is a note on stderr (with --json also a line
    ``{"warnings": [...]}``), as is each of the run's warnings before the first frame."""
    from collections import deque

    from rich.live import Live

    from wiloc.decisions import Decision

    started, decided = time.perf_counter(), 0
    latest: deque[Decision] = deque(maxlen=10)
    notes = Notes()  # frames left out
    warned = Notes()
    for line in run.warnings:
        warned.add("warning", line)
    if as_json and warned:
        print(json.dumps({"warnings": warned}), flush=True)

    def view() -> Table:
        rate = decided / max(time.perf_counter() - started, 1e-9)
        live_table = Table(title=cell(f"following {query} -> {run.path}"),
                           caption=f"{run.resumed + decided} frames ({run.resumed} resumed), {rate:.1f} frames/s; Ctrl-C stops")
        for column in FOLLOW_COLUMNS:
            live_table.add_column(column, justify="left" if column in ("frame", "match", "stage") else "right")
        for d in latest:
            live_table.add_row(cell(d.frame), cell(d.match_name), cell(d.confidence), cell(d.new_place), d.stage)
        return fit(live_table)

    live = Live(view(), console=out, auto_refresh=False) if out.is_terminal and not as_json else None
    if live is None and not as_json:
        print("\t".join(FOLLOW_COLUMNS), flush=True)
    with live if live is not None else contextlib.nullcontext():
        for event in run:
            if isinstance(event, Decision):
                decided += 1
                latest.append(event)
                if live is not None:
                    live.update(view(), refresh=True)
                elif as_json:
                    print(json.dumps(json_ready({"frame": event.frame, "match": event.match_name,
                                                 "confidence": event.confidence, "new_place": event.new_place,
                                                 "stage": event.stage})), flush=True)
                else:
                    print(f"{_field(event.frame)}\t{_field(event.match_name or '-')}\t{cell(event.confidence)}\t"
                          f"{cell(event.new_place)}\t{event.stage}", flush=True)
            else:  # --json names the file by its absolute path, as every --json does
                notes.add(event.kind, str(replace(event, path=Path(absolute_frame(event.path))) if as_json else event))
                if as_json:  # the line on stderr, as every --json carries it
                    print(json.dumps({"warnings": notes[-1:]}), flush=True)
    ended = (f"no new frame for {run.idle:g} s; {decided} frames decided ({run.resumed} resumed before), "
             f"{sum(n.startswith('skipped:') for n in notes)} left out; results in {run.path.absolute()}")
    if run.idle is None or as_json:
        return
    if live is None:
        print(f"# ended: {ended}", flush=True)
    else:  # on a terminal, under the live table: why the run ended and where its rows are
        out.print(f"ended: {ended}", highlight=False, markup=False, soft_wrap=True)


def _field(name: str) -> str:
    """A frame's name as one field of a tab-separated line: its tabs and line breaks, which would
    split the field or the line, written as ``\\t``, ``\\n`` and ``\\r`` (a backslash doubled)."""
    return name.replace("\\", "\\\\").replace("\t", "\\t").replace("\n", "\\n").replace("\r", "\\r")
