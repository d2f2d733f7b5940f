"""How the command line shows results: rich tables that stay readable at 80 columns, JSON with one
key scheme, and the progress bar.

Tables never cut a cell short nor break a word: names wrap within their column at separators
only (``catgraph/`` then ``sad``: :class:`wiloc.wrapping.Words`), and a table too wide for the
console drops its vertical rules and edges (:func:`fit`); in one too narrow for every word,
headers and names fold onto more lines first and numbers last, never losing a character. Paths
are shown by their own name, or as many trailing parts as keep two of the same name apart
(:func:`wiloc.labels.short_names`); ``--json`` carries the full paths. JSON keys are snake_case
(``recall_at_100``, ``images_per_second``); docs/formats.md lists them per command.
"""
from __future__ import annotations

import codecs
import json
import math
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from rich import box
from rich.markup import escape
from rich.measure import Measurement
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from wiloc.candidates import RANKED
from wiloc.cli.core import err, out
from wiloc.cli.scoring import slice_columns
from wiloc.evaluation.reliability import NEW_PLACE_KEYS
from wiloc.labels import threshold_text
from wiloc.reprs import number_label
from wiloc.text_tables import Digits
from wiloc.wrapping import Words

if TYPE_CHECKING:
    from wiloc import api

CUT_CAPTION = "at a cut: P precision, R recall, n frames accepted (decided, confidence >= cut)"
METRIC_LABELS = {"recall_at_100": "recall at 100 % precision", "recall_at_99": "recall at 99 % precision",
                 "recall_at_90": "recall at 90 % precision", "auc": "area under PR curve", "max_f1": "max F1",
                 "max_f1_threshold": "threshold at max F1", "recall_at_1": "R@1 (best match right)",
                 "frames": "frames", "decided": "decided frames", "with_true_match": "frames with a true match",
                 "ece": "ECE", "brier": "Brier score", "mean_confidence": "mean confidence",
                 "share_correct": "share correct"}
#: Columns of the runs-down metrics table (one row per results file), with short headers.
RUN_COLUMNS = {"recall_at_100": "R\n@100%P", "recall_at_99": "R\n@99%P", "recall_at_90": "R\n@90%P",
               "auc": "AUC", "max_f1": "max\nF1", "recall_at_1": "R@1", "decided": "deci-\nded"}
CALIBRATION_COLUMNS = {"ece": "ECE", "brier": "Brier", "mean_confidence": "mean\nconf.",
                       "share_correct": "share\ncorrect"}
#: P(new place)'s calibration (``NEW_PLACE_KEYS`` + a calibration key), for runs that give it.
NEW_PLACE_COLUMNS = {NEW_PLACE_KEYS + "ece": "ECE", NEW_PLACE_KEYS + "brier": "Brier",
                     NEW_PLACE_KEYS + "mean_confidence": "mean\nP(new)", NEW_PLACE_KEYS + "share_correct": "share\nnew"}
NEW_PLACE_LABELS = {NEW_PLACE_KEYS + "ece": "P(new place): ECE", NEW_PLACE_KEYS + "brier": "P(new place): Brier",
                    NEW_PLACE_KEYS + "mean_confidence": "mean P(new place)",
                    NEW_PLACE_KEYS + "share_correct": "share without a true match"}
NEW_PLACE_CAPTION = ("P(new place) against the frames without a true match in the map; at a cut: P precision, "
                     "R recall of those frames, n frames with P(new place) >= cut")


@contextmanager
def progress_bar(enabled: bool) -> Iterator[api.Progress | None]:
    """A rich progress bar on stderr, one task per step label; None when disabled."""
    if not enabled:
        yield None
        return
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, console=err, transient=True, disable=not err.is_terminal) as bar:
        tasks: dict[str, Any] = {}

        def update(label: str, done: int, total: int) -> None:
            if label not in tasks:
                tasks[label] = bar.add_task(label, total=total)
            bar.update(tasks[label], completed=done, total=total)
        yield update


def json_ready(value: Any) -> Any:
    """``value`` as JSON holds it: NaN and infinities as null, numpy scalars as numbers."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if hasattr(value, "item"):
        return json_ready(value.item())
    return value


def print_json(data: Any) -> None:
    """``data`` as JSON on stdout, indented: plain text whatever the terminal (no colour, even with
    FORCE_COLOR set, and no wrapping: a script reads it), non-ASCII characters escaped where
    stdout cannot encode them (PYTHONIOENCODING=ascii)."""
    stream = sys.stdout
    utf8 = codecs.lookup(getattr(stream, "encoding", None) or "ascii").name == "utf-8"
    stream.write(json.dumps(json_ready(data), indent=2, ensure_ascii=not utf8) + "\n")


def print_command_json(command: str, items: str, rows: list[dict[str, Any]], warnings: Sequence[str],
                       **extra: Any) -> None:
    """A command's --json, one shape for all (``wiloc/schema/output.schema.json``, docs/formats.md):
    ``command``, its ``results`` (what it made: descriptors, vocabularies) or ``runs`` (localization
    runs, each with its ``method``, ``descriptor`` and ``traversal``), every line it printed on
    stderr as ``warnings``, then the command's own keys."""
    print_json({"command": command, items: rows, "warnings": list(warnings), **extra})


def cell(value: Any, digits: int = 3) -> str:
    """A table cell: ``digits`` decimals ("-" for NaN or None; a number of a million or more in
    scientific notation, so that a huge one keeps the table readable), "yes" or nothing for a
    flag; text is shown as it is (a label such as ``online [run-b]`` is no markup)."""
    if isinstance(value, bool):
        return "yes" if value else ""
    if isinstance(value, float):
        if not math.isfinite(value):
            return "-"
        return f"{value:.{digits}e}" if abs(value) >= 1e6 else f"{value:.{digits}f}"
    return "-" if value is None else escape(str(value))


def name(value: Any) -> Words | str:
    """A table cell of text (a name, a label): wrapped at separators, never inside a word."""
    return "-" if value is None else Words(str(value))


#: A table's styles from roomy to compact: as made, then no vertical rules nor edges, then one
#: space between columns (box, show_edge, pad_edge, padding; None: the table's own).
_COMPACT = (None, (box.SIMPLE_HEAD, False, False, (0, 1)), (box.SIMPLE_HEAD, False, False, (0, 0)))


def _column_widths(view: Table) -> tuple[list[int], list[int]]:
    """Each column's narrowest width that keeps every word whole and its width with every line
    whole: the minimum and maximum measures of its cells and header (:class:`Words`, numbers,
    ``P 1.000`` lines)."""
    ranges = [[Measurement.get(out, out.options, item) for item in (column.header, *column.cells)]
              for column in view.columns]
    return [max(r.minimum for r in column) for column in ranges], [max(r.maximum for r in column) for column in ranges]


def _frame_width(view: Table) -> int:
    """What a table takes besides its columns' content: its edges and the lines between columns
    (when it has a box) and each column's padding (the outer padding only with ``pad_edge``)."""
    _, right, _, left = view.padding
    lines = (2 if view.show_edge else 0) + len(view.columns) - 1 if view.box else 0
    return lines + (left + right) * len(view.columns) - (0 if view.pad_edge else left + right)


def _styled_to_fit(view: Table, widths: list[int]) -> bool:
    """Give ``view`` the first style of :data:`_COMPACT` in which columns of ``widths`` fit the
    console (the most compact when none does); whether one does."""
    own = (view.box, view.show_edge, view.pad_edge, view.padding)
    for style in _COMPACT:
        view.box, view.show_edge, view.pad_edge, view.padding = style or own
        if sum(widths) + _frame_width(view) <= out.width:
            return True
    return False


def words_fit(view: Table) -> bool:
    """Whether ``view`` fits the console without breaking a word (in some style of :data:`_COMPACT`)."""
    own = (view.box, view.show_edge, view.pad_edge, view.padding)
    fits = _styled_to_fit(view, _column_widths(view)[0])
    view.box, view.show_edge, view.pad_edge, view.padding = own
    return fits


def _floors(view: Table) -> list[int]:
    """How narrow each column may get before one of its values folds: a column of values
    (numbers, whole lines: no cell that wraps as a name does, :func:`name`) as wide as its widest
    cell, one of names one character; headers do not count (they fold first)."""
    return [1 if any(isinstance(c, Words) and not c.whole_lines for c in column.cells)
            else max([1, *(Measurement.get(out, out.options, c).minimum for c in column.cells)])
            for column in view.columns]


def _narrowed(widths: list[int], floors: list[int], room: int) -> list[int]:
    """``widths`` narrowed a character at a time, the widest column first and none below its
    floor, until they take ``room`` or each is at its floor."""
    widths = list(widths)
    while sum(widths) > room:
        above = [i for i, (width, floor) in enumerate(zip(widths, floors)) if width > floor]
        if not above:
            break
        widths[max(above, key=widths.__getitem__)] -= 1
    return widths


def fit(view: Table) -> Table:
    """``view`` with column widths that keep every word whole when it can, and every character
    always: every table goes through here. Rich's own sharing of a narrow console narrows columns
    below their widest word and cuts what does not fit; instead, in the first style of
    :data:`_COMPACT` that lets every line fit whole, or else every word: each column at least as
    wide as its widest word and the room left shared out in proportion to what each would take
    more. When not even every word fits, in the most compact style headers and names narrow
    before values (:func:`_floors`), then every column, each folding what does not fit."""
    for column in view.columns:
        column.overflow = "fold"  # a plain cell wider than its column: onto more lines, not cut
    lows, highs = _column_widths(view)
    if _styled_to_fit(view, highs):
        return view
    if not _styled_to_fit(view, lows):
        room = out.width - _frame_width(view)
        widths = _narrowed(_narrowed(lows, _floors(view), room), [1] * len(lows), room)
        for column, width in zip(view.columns, widths):
            column.width = width
        return view
    room = out.width - _frame_width(view) - sum(lows)
    more = [high - low for low, high in zip(lows, highs)]
    for column, low, m in zip(view.columns, lows, more):
        column.width = low + room * m // max(sum(more), 1)
    return view


def table(title: str, rows: list[dict[str, Any]], columns: Sequence[str] | None = None,
          labels: dict[str, str] | None = None, caption: str | None = None,
          digits: dict[str, int] | None = None) -> Table:
    """A rich table of ``rows`` (dicts), ``columns`` in order, headed by ``labels`` where given,
    numbers with 3 decimals unless ``digits`` says otherwise. Text wraps at separators, never
    inside a word; ready-made cells (:func:`at_cut`'s) are shown as they are."""
    columns = list(columns or (rows[0] if rows else []))
    view = Table(title=escape(title), caption=caption)
    for column in columns:
        first = rows[0].get(column) if rows else ""
        view.add_column(Words((labels or {}).get(column, column)),
                        justify="left" if isinstance(first, (str, Words)) else "right")
    for row in rows:
        view.add_row(*[row[c] if isinstance(row.get(c), Words) else name(row[c]) if isinstance(row.get(c), str)
                       else cell(row.get(c), (digits or {}).get(c, 3)) for c in columns])
    return fit(view)


def at_cut(row: dict[str, Any], cut: float, prefix: str = "") -> Words:
    """Precision, recall and accepted frames at one confidence cut of a table row (its keys after
    ``prefix``), one a line, each line whole."""
    at = number_label(cut)
    return Words(f"P {cell(row[f'{prefix}precision@{at}'])}\nR {cell(row[f'{prefix}recall@{at}'])}\n"
                 f"n {cell(row[f'{prefix}accepted@{at}'], 0)}", whole_lines=True)


def new_place_view(rows: list[dict[str, Any]], cuts: Sequence[float], ground_truth: str,
                   heads: list[str]) -> Table | None:
    """P(new place)'s calibration, one row per run that gives it (``heads`` name the run), with
    precision and recall of "new place" at each cut; None when no run gives it."""
    given = [row for row in rows if _says_new_place(row)]
    if not given:
        return None
    cut_columns = {f"cut {number_label(cut)}": cut for cut in cuts}
    shown = [{**{h: row[h] for h in heads}, **{k: row[k] for k in NEW_PLACE_COLUMNS},
              **{name: at_cut(row, cut, NEW_PLACE_KEYS) for name, cut in cut_columns.items()}} for row in given]
    return table(f"P(new place) (ground truth: {ground_truth})", shown, [*heads, *NEW_PLACE_COLUMNS, *cut_columns],
                 NEW_PLACE_COLUMNS, caption=NEW_PLACE_CAPTION)


def recall_at_keys(rows: Sequence[dict[str, Any]]) -> list[str]:
    """The Recall@N keys (``recall_at_N``, N > 1: runs whose results rank the map) that some row
    has a value for, by N; not the recall at a precision (``recall_at_100``, N above any ranking)."""
    found = {key for row in rows for key, value in row.items() if key.startswith("recall_at_")
             and key.removeprefix("recall_at_").isdigit() and 1 < int(key.removeprefix("recall_at_")) <= RANKED
             and not _missing(value)}
    return sorted(found, key=lambda key: int(key.removeprefix("recall_at_")))


def recall_at_label(key: str) -> str:
    """A Recall@N key's row label in the metrics-down table."""
    n = key.removeprefix("recall_at_")
    return f"R@{n} (a true match in the {n} best)"


def metrics_views(rows: list[dict[str, Any]], cuts: Sequence[float], ground_truth: str) -> list[Table]:
    """`wiloc evaluate`'s tables: metrics down and one column per results file while the runs fit
    the console with every metric's label on one line; else one row per results file, in two
    tables, and a third for Recall@N when a run has it."""
    title = f"evaluate (ground truth: {ground_truth})"
    ranked = recall_at_keys(rows)
    keys = list(METRIC_LABELS)
    down = _metrics_down(rows, cuts, title, [*keys[:keys.index("recall_at_1") + 1], *ranked,
                                             *keys[keys.index("recall_at_1") + 1:]])
    if words_fit(down):
        return [fit(down)]
    cut_columns = {f"cut {number_label(cut)}": cut for cut in cuts}
    calibration = [{"run": row["run"], **{k: row[k] for k in CALIBRATION_COLUMNS},
                    **{name: at_cut(row, cut) for name, cut in cut_columns.items()}} for row in rows]
    views = [table(title, rows, ["run", *RUN_COLUMNS], RUN_COLUMNS,
                   caption="R@x%P: recall at x % precision; R@1: best match right"),
             table(f"calibration and fixed confidence cuts (ground truth: {ground_truth})", calibration,
                   ["run", *CALIBRATION_COLUMNS, *cut_columns], CALIBRATION_COLUMNS, caption=CUT_CAPTION)]
    if ranked:
        columns = {key: f"R@{key.removeprefix('recall_at_')}" for key in ["recall_at_1", *ranked]}
        views.append(table(f"Recall@N (ground truth: {ground_truth})", rows, ["run", *columns], columns,
                           caption="R@N: a true match among the N best map frames (-: not ranked)"))
    if (view := new_place_view(rows, cuts, ground_truth, ["run"])) is not None:
        views.append(view)
    return views


def _metrics_down(rows: list[dict[str, Any]], cuts: Sequence[float], title: str, keys: list[str]) -> Table:
    new_place = any(_says_new_place(row) for row in rows)
    view = Table(title=escape(title), caption=CUT_CAPTION + ("; P(new place) >= cut: P the share of those frames "
                                                             "without a true match, R of the frames without one"
                                                             if new_place else ""))
    view.add_column("")
    for row in rows:
        view.add_column(Words(f"{row['method']}\n{row['traversal']}"), justify="right")
    view.add_row(Words("results", whole_lines=True), *[name(row["results"]) for row in rows])
    for key in keys:
        view.add_row(Words(METRIC_LABELS.get(key) or recall_at_label(key), whole_lines=True),
                     *[threshold_text(row.get(key)) if key == "max_f1_threshold" else cell(row.get(key))
                       for row in rows])
    for cut in cuts:
        view.add_row(f"cut {number_label(cut)}", *[at_cut(row, cut) for row in rows])
    if new_place:
        for key, label in NEW_PLACE_LABELS.items():
            view.add_row(Words(label, whole_lines=True), *[cell(row.get(key)) for row in rows])
        for cut in cuts:
            view.add_row(Words(f"P(new place) >= {number_label(cut)}", whole_lines=True),
                         *[at_cut(row, cut, NEW_PLACE_KEYS) if _says_new_place(row) else "-" for row in rows])
    return view


def _says_new_place(row: dict[str, Any]) -> bool:
    """Whether a table row's run gives P(new place) (its calibration keys are there)."""
    return not _missing(row.get(NEW_PLACE_KEYS + "ece"))


def cut_views(comparison: api.Comparison, cuts: Sequence[float]) -> list[Table]:
    """Per traversal, one row per method: calibration and precision / recall at each fixed cut."""
    tables = []
    for traversal, group in comparison.cut_table.groupby("traversal", sort=False):
        view = Table(title=cell(f"Calibration and fixed confidence cuts: {traversal} ({comparison.ground_truth})"),
                     caption=CUT_CAPTION)
        view.add_column("method")
        for column in CALIBRATION_COLUMNS.values():
            view.add_column(column, justify="right")
        for cut in cuts:
            view.add_column(f"cut\n{number_label(cut)}")
        for row in group.to_dict(orient="records"):
            view.add_row(name(row["method"]), *[cell(row[key]) for key in CALIBRATION_COLUMNS],
                         *[at_cut(row, cut) for cut in cuts])
        tables.append(fit(view))
    return tables


#: Table I's columns when it lists one run a row, with short headers (the caption says them).
TABLE1_COLUMNS = {"recall_at_100": "R\n@100%P", "recall_at_99": "R\n@99%P", "recall_at_90": "R\n@90%P", "auc": "AUC"}


def table1_view(comparison: api.Comparison) -> Table:
    """Table I: recall at 100/99/90 % precision, AUC and Recall@N; as the paper has it (one row
    per traversal, a column per method) when that fits the console with every line whole, else
    one row per run, a column per metric."""
    rows = comparison.table1.to_dict(orient="records")
    ranked = ["recall_at_1", *recall_at_keys(rows)]
    recall_at = f"R@{'/'.join(key.removeprefix('recall_at_') for key in ranked)}"
    title = escape(f"Table I: recall at 100 / 99 / 90 % precision (plus AUC, {recall_at}); {comparison.ground_truth}")
    methods, traversals = list(dict.fromkeys(r["method"] for r in rows)), list(dict.fromkeys(r["traversal"] for r in rows))
    cells = {(r["traversal"], r["method"]): _table1_cell(r, ranked) for r in rows}
    widths = [max(len(line) for key, text in cells.items() if key[1] == m for line in text.split("\n")) for m in methods]
    if max(len("traversal"), *map(len, traversals)) + sum(max(w, len(m)) + 3 for w, m in zip(widths, methods)) + 4 <= out.width:
        view = Table(title=title)
        view.add_column("traversal")
        for m in methods:
            view.add_column(Words(m), justify="right")
        for traversal in traversals:
            view.add_row(name(traversal), *[Words(cells[traversal, m], whole_lines=True) if (traversal, m) in cells
                                            else "" for m in methods])
        return fit(view)
    shown = [{"traversal": r["traversal"], "method": r["method"],  # percentages: values, not names
              **{key: Words(f"{r[key]:.1%}", whole_lines=True) for key in ("recall_at_100", "recall_at_99",
                                                                           "recall_at_90")},
              **{key: None if _missing(r.get(key)) else float(r[key]) for key in ("auc", *ranked)}} for r in rows]
    labels = {**TABLE1_COLUMNS, **{key: f"R@{key.removeprefix('recall_at_')}" for key in ranked}}
    view = table(title, shown, ["traversal", "method", *labels], labels,
                 caption="R@x%P: recall at x % precision; R@N: a true match among the N best (-: not ranked)")
    for column in view.columns[2:5]:  # percentages: text, but numbers to the eye
        column.justify = "right"
    return view


def _table1_cell(r: dict[str, Any], ranked: list[str]) -> str:
    """One run's cell of Table I as the paper lays it out: recall at 100 / 99 / 90 % precision,
    AUC, and the Recall@N it has."""
    at = [key for key in ranked if not _missing(r.get(key))]
    return (f"{r['recall_at_100']:.1%} / {r['recall_at_99']:.1%} / {r['recall_at_90']:.1%}\n"
            f"AUC {r['auc']:.3f}\nR@{'/'.join(key.removeprefix('recall_at_') for key in at)} "
            f"{' / '.join(f'{r[key]:.3f}' for key in at)}")


def run_records(comparison: api.Comparison) -> list[dict[str, Any]]:
    """A comparison's runs for --json: per run its method, descriptor and traversal, its label in
    the tables (``label``: the method, with the descriptor or file where needed to tell runs
    apart), its results file, Table I's metrics (without the Recall@N keys of runs that have
    none) and its calibration."""
    rows = comparison.table1.to_dict(orient="records")
    ranked = set(recall_at_keys(rows))
    return [{"method": e.method, "descriptor": e.results.header.descriptor, "traversal": row["traversal"],
             "label": row["method"], "results": None if e.path is None else str(e.path.resolve()),
             **{key: value for key, value in row.items() if key not in ("method", "traversal")
                and not (key in ranked and _missing(value))}, **e.calibration_dict()}
            for row, e in zip(rows, comparison.evaluations)]


def compared_runs(comparison: api.Comparison) -> list[dict[str, Any]]:
    """A comparison's runs as compare's and demo's --json give them: :func:`run_records`, each
    with the warnings its ground truth gave (``truth_warnings``) and, scored on a slice of its
    frames, ``frame_slice`` and ``run_frames`` (:func:`slice_columns`), as evaluate's --json."""
    return [{**record, **slice_columns(e), "truth_warnings": e.truth.warnings}
            for record, e in zip(run_records(comparison), comparison.evaluations)]


def _missing(value: Any) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


def table2_view(comparison: api.Comparison) -> Table:
    """Table II: the global threshold per method and precision (its digits by :func:`threshold_text`),
    recall per traversal, worst marked."""
    t2 = comparison.table2
    traversals = list(dict.fromkeys(t2["traversal"]))
    view = Table(title=escape(f"Table II: one global threshold per method (worst traversal marked *); "
                              f"{comparison.ground_truth}"))
    for column in ("method", "precision", "threshold", *traversals):
        view.add_column(Words(column), justify="left" if column == "method" else "right")
    for (method, target), group in t2.groupby(["method", "precision"], sort=False):
        cells = {row.traversal: f"{row.recall:.1%}{' *' if row.worst else ''}" for row in group.itertuples()}
        threshold = group["threshold"].iloc[0]
        view.add_row(name(method), f"{number_label(target)}%", threshold_text(float(threshold)),
                     *[cells.get(t, "") for t in traversals])
    return fit(view)


def comparison_records(comparison: api.Comparison) -> list[tuple[str, list[dict[str, Any]], list[str], dict[str, str]]]:
    """`compare`'s tables as plain records for CSV, Markdown and LaTeX: (title, rows, columns,
    one-line headers) of Table I (one row per run), the calibration with P / R / n at each cut,
    P(new place)'s the same (the runs that say it; left out when none does) and Table II, last."""
    table1 = comparison.table1.to_dict(orient="records")
    ranked = ["recall_at_1", *recall_at_keys(table1)]
    heads = {"recall_at_100": "R@100%P", "recall_at_99": "R@99%P", "recall_at_90": "R@90%P", "auc": "AUC",
             **{key: f"R@{key.removeprefix('recall_at_')}" for key in ranked}}
    at = [key.removeprefix("precision@") for key in comparison.cut_table.columns if key.startswith("precision@")]
    at_cuts = {f"{key}@{cut}": f"{head}@{cut}" for cut in at
               for key, head in (("precision", "P"), ("recall", "R"), ("accepted", "n"))}
    calibration = {"ece": "ECE", "brier": "Brier", "mean_confidence": "mean conf.", "share_correct": "share correct",
                   **at_cuts}
    new_place = {NEW_PLACE_KEYS + key: head for key, head in
                 {**calibration, "mean_confidence": "mean P(new place)", "share_correct": "share new"}.items()}
    counts = [key for key in new_place if key.startswith(NEW_PLACE_KEYS + "accepted@")]
    records = comparison.cut_table.to_dict(orient="records")
    cuts = [{**row, **{key: int(row[key]) if _says_new_place(row) else None for key in counts}}  # counts, not floats
            for row in records] if any(map(_says_new_place, records)) else records  # beside runs without; none: none
    given = [row for row in cuts if _says_new_place(row)]
    return [(f"Table I: recall at 100 / 99 / 90 % precision, AUC and Recall@N; {comparison.ground_truth}",
             table1, ["traversal", "method", *heads], heads),
            (f"Calibration and fixed confidence cuts ({CUT_CAPTION}); {comparison.ground_truth}", cuts,
             ["traversal", "method", *calibration], calibration),
            *([(f"{NEW_PLACE_CAPTION}; {comparison.ground_truth}", given,
                ["traversal", "method", *new_place], new_place)] if given else []),
            (f"Table II: one global threshold per method (worst traversal marked); {comparison.ground_truth}",
             [{**row, "precision": f"{number_label(row['precision'])}%", "threshold": Digits(threshold_text(row["threshold"]))}
              for row in comparison.table2.to_dict(orient="records")],
             ["method", "precision", "threshold", "traversal", "recall", "worst"], {})]
