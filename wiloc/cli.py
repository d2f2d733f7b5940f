"""The `wiloc` command line: parse options, call wiloc.api, render rich tables or JSON."""
from __future__ import annotations

import contextlib
import functools
import json
import os
import time
from dataclasses import asdict
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

# FFmpeg inside OpenCV reads its log level once, when cv2 is loaded: keep its lines about damaged
# videos ("[mpeg4 @ 0x...] header damaged") off the terminal, since wiloc reports them itself.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET

from wiloc import __version__, api  # loads cv2
from wiloc.candidates import DEFAULT_EXCLUDE_RECENT
from wiloc.cli_params import flag, method_params, with_method_options
from wiloc.errors import EXIT_INTERRUPTED, WilocError
from wiloc.methods.registry import METHODS, method_class
from wiloc.reliability import DEFAULT_CUTS

app = typer.Typer(
    add_completion=False, no_args_is_help=True, rich_markup_mode="rich",
    help="Appearance-based localization with whole-image descriptors and a probability model "
         "learned online.\n\nExample: [bold]wiloc demo[/bold], then\n\n"
         "  wiloc localize data/day_left --map data/day_right --descriptor sad --method online")
out = Console()
err = Console(stderr=True)


def _error(message: str) -> None:
    """One unwrapped `error:` line on stderr."""
    err.print(f"[bold red]error:[/bold red] {escape(message)}", highlight=False, soft_wrap=True)


def _fail(message: str, code: int) -> None:
    _error(message)
    raise typer.Exit(code)


def _note(kind: str, message: str) -> None:
    """One unwrapped line on stderr about something left out or worth knowing."""
    err.print(f"[yellow]{kind}[/yellow] {escape(message)}", highlight=False, soft_wrap=True)


def handles_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """One line and an exit code for input problems and Ctrl-C; never a traceback."""
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except WilocError as exc:
            _fail(f"{flag(exc.parameter)}: {exc.problem}" if exc.parameter else str(exc), exc.exit_code)
        except OSError as exc:
            _fail(f"{exc.filename}: {exc.strerror}" if exc.filename else str(exc), 1)
        except KeyboardInterrupt:
            _fail("interrupted; finished work is kept in the cache, rerun to resume", EXIT_INTERRUPTED)
    return wrapper


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


def _json_ready(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if hasattr(value, "item"):
        return _json_ready(value.item())
    return value


def _print_json(data: Any) -> None:
    out.print_json(json.dumps(_json_ready(data)))


def _table(title: str, rows: list[dict[str, Any]], columns: list[str] | None = None,
           labels: dict[str, str] | None = None) -> Table:
    """A rich table of ``rows`` (dicts), ``columns`` in order, headed by ``labels`` where given."""
    columns = columns or (list(rows[0]) if rows else [])
    table = Table(title=title)
    for column in columns:
        table.add_column((labels or {}).get(column, column),
                         justify="left" if not rows or isinstance(rows[0].get(column), str) else "right")
    for row in rows:
        table.add_row(*[_cell(row.get(c)) for c in columns])
    return table


def _cell(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else ""
    if isinstance(value, float):
        return "-" if not math.isfinite(value) else f"{value:.3f}"
    return "" if value is None else str(value)


def _descriptor_params(descriptor: str, crop: str, vocabulary: str | None = None,
                       cache: Path | None = None) -> dict[str, str]:
    """The descriptor parameters the command line sets: only `sad` takes --crop, only `bow`
    (which needs it) --vocabulary."""
    if (vocabulary is not None) != (descriptor == "bow"):
        _fail("--vocabulary goes with --descriptor bow, and bow needs it", 2)
    if descriptor == "bow":
        from wiloc.cache import Cache
        return {"file": str(api.vocabulary_file(vocabulary, Cache(cache)))}
    return {"crop": crop} if descriptor == "sad" else {}


VocabularyOption = Annotated[Optional[str], typer.Option(
    help="bow: the vocabulary (its file, or its key in the cache) from `wiloc vocabulary`.")]


def _version(value: bool) -> None:
    if value:
        out.print(f"wiloc {__version__}")
        raise typer.Exit()


@app.callback()
def main(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                      help="Print the version and exit.")) -> None:
    """wiloc: have I been here before, where, and how sure am I?"""


# ------------------------------------------------------------------------------------------ describe

EveryOption = Annotated[int, typer.Option(help="Videos: every K-th frame of the cut.", rich_help_panel="video files")]
FpsOption = Annotated[Optional[float], typer.Option(help="Videos: about F frames per second (by timestamp), instead of --every.", rich_help_panel="video files")]
StartOption = Annotated[str, typer.Option(help="Videos: first frame, an index (120) or seconds (12.5s).", rich_help_panel="video files")]
StopOption = Annotated[Optional[str], typer.Option(help="Videos: end of the cut (excluded), an index or seconds; default: the end.", rich_help_panel="video files")]


@app.command()
@handles_errors
def describe(
    folders: list[Path] = typer.Argument(None, help="Image folders or video files (one traversal each)."),
    descriptor: str = typer.Option("sad", "--descriptor", "-d", help="sad | gist | brisk-gist | bow"),
    crop: str = typer.Option("none", help="sad only: none | top-half"),
    vocabulary: VocabularyOption = None,
    import_file: Optional[Path] = typer.Option(None, "--import", help="External N x D matrix (.npy, .csv, .h5)."),
    names: Optional[Path] = typer.Option(None, help="With --import .npy: text file of frame names, one a line."),
    metric: str = typer.Option("l1", help="With --import: l1 | sqeuclidean | hamming | cosine"),
    every: EveryOption = 1,
    fps: FpsOption = None,
    start: StartOption = "0",
    stop: StopOption = None,
    list_cache: bool = typer.Option(False, "--list", help="Show what the cache holds."),
    cache: Optional[Path] = typer.Option(None, envvar="WILOC_CACHE", help="Cache folder."),
    jobs: Optional[int] = typer.Option(None, "--jobs", "-j", help="Worker processes for image folders (default: all cores)."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Compute whole-image descriptors of image folders or video files into the HDF5 cache.

    Example: wiloc describe data/gardens-point-walking/day_right --descriptor gist
    """
    from wiloc.cache import Cache
    store = Cache(cache)
    if list_cache:
        infos = store.list_entries()
        if as_json:
            _print_json([asdict(info) for info in infos])
            return
        rows = [{"folder": info.folder, "descriptor": info.descriptor,
                 "params": ", ".join(f"{k}={v}" for k, v in sorted(info.params.items())),
                 "frames": info.frames, "complete": info.complete, "MB": f"{info.size / 1e6:.1f}",
                 "updated": info.updated[:16].replace("T", " "), "problem": info.problem} for info in infos]
        columns = ["folder", "descriptor", "params", "frames", "complete", "MB", "updated"]
        out.print(_table(f"cache {store.root}", rows, columns + ["problem"] * any(i.problem for i in infos)))
        return
    if import_file is None and not folders:
        _fail("give image folders, video files, --import FILE or --list", 2)
    sampling = api.Sampling(every=every, fps=fps, start=start, stop=stop)
    with progress_bar(not as_json) as progress:
        if import_file is not None:
            reports = [api.import_descriptors(import_file, metric=metric, names=names, cache=store)]
        else:
            reports = api.describe(folders, descriptor, descriptor_params=_descriptor_params(descriptor, crop, vocabulary, cache),
                                   cache=store, jobs=jobs, progress=progress, sampling=sampling)
    rows = [{"folder": str(given), "frames": r.frames, "descriptor": r.descriptor,
             "shape": "x".join(map(str, r.shape)), "computed": r.computed, "reused": r.reused,
             "failed": len(r.failed), "images/s": f"{r.images_per_second:.1f}" if r.computed else "-"}
            for given, r in zip([import_file] if import_file is not None else folders, reports)]
    if as_json:
        _print_json([{**row, "failed_frames": [list(f) for f in r.failed], "ignored": list(r.ignored)}
                     for row, r in zip(rows, reports)])
    else:
        out.print(_table("describe", rows))
        for r in reports:
            for name, reason in r.failed if not r.video else ():
                _note("skipped", f"{Path(r.folder) / name}: {reason}")
            if len(r.sizes) > 1:
                _note("note", f"{r.folder}: images of {len(r.sizes)} different sizes")
    # A video that stops decoding early is an error, after its good frames went into the cache.
    problems = [f"{r.folder}: {reason}" for r in reports if r.video for _, reason in r.failed]
    problems += [f"{r.folder}: no image could be described (see the lines above)"
                 for r in reports if r.entry.data.shape[0] == 0]
    for problem in problems:
        _error(problem)
    if problems:
        raise typer.Exit(1)


# ---------------------------------------------------------------------------------------- vocabulary

@app.command()
@handles_errors
def vocabulary(
    folders: list[Path] = typer.Argument(..., help="Training image folders (never the pair you will test on)."),
    feature: str = typer.Option("sift", help="Local feature: sift (k-means) or orb (k-majority)."),
    words: int = typer.Option(1000, help="K, the number of visual words."),
    max_features: int = typer.Option(500, help="Local features kept per image, strongest first."),
    max_side: int = typer.Option(640, help="Images are shrunk so their longer side is at most this many pixels."),
    iterations: int = typer.Option(25, help="At most this many clustering rounds."),
    seed: int = typer.Option(0, help="Seeds the initial centres."),
    cache: Optional[Path] = typer.Option(None, envvar="WILOC_CACHE", help="Cache folder."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Cluster the local features of training folders into a visual vocabulary, kept in the cache,
    for the bow descriptor and FAB-MAP.

    Example: wiloc vocabulary data/night_right --words 1000, then
    wiloc localize data/day_left --map data/day_right --descriptor bow --vocabulary KEY --method fabmap
    """
    from wiloc.cache import Cache
    params = {"feature": feature, "words": words, "max_features": max_features, "max_side": max_side,
              "iterations": iterations, "seed": seed}
    with progress_bar(not as_json) as progress:
        report = api.vocabulary(folders, params, cache=Cache(cache), progress=progress)
    row = {"key": report.vocabulary.key, "words": report.vocabulary.n_words,
           "training frames": len(report.vocabulary.training_frames), "built": report.built,
           "seconds": round(report.seconds, 1), "file": str(report.path)}
    if as_json:
        _print_json({**{k.replace(" ", "_"): v for k, v in row.items()},
                     "failed": [list(item) for item in report.failed]})
        return
    for path, reason in report.failed:
        _note("skipped", f"{path}: {reason}")
    out.print(_table("vocabulary", [row]))


# ------------------------------------------------------------------------------------------ localize

@app.command()
@handles_errors
@with_method_options
def localize(
    queries: list[Path] = typer.Argument(..., help="Query traversal folder(s) (or descriptor matrix files)."),
    reference: Optional[Path] = typer.Option(None, "--map", "-m", help="Reference traversal; omit for sequence mode (loop closure)."),
    descriptor: str = typer.Option("sad", "--descriptor", "-d", help="sad | gist | brisk-gist | bow (with --vocabulary; fabmap and catgraph then read FAB-MAP's evidence)"),
    crop: str = typer.Option("none", help="sad only: none | top-half"),
    vocabulary: VocabularyOption = None,
    metric: Optional[str] = typer.Option(None, help="For descriptor matrix files: l1 | sqeuclidean | hamming | cosine"),
    method: str = typer.Option("online", help=" | ".join(METHODS)),
    exclude_recent: int = typer.Option(DEFAULT_EXCLUDE_RECENT, "--exclude-recent", "-R", help="Recent frames excluded as candidates (sequence mode) and around each map frame when learning from the map."),
    train_query: Optional[Path] = typer.Option(None, help="trained: labelled training query traversal.", rich_help_panel="trained inputs"),
    train_map: Optional[Path] = typer.Option(None, help="trained: its reference traversal.", rich_help_panel="trained inputs"),
    train_gt: Optional[str] = typer.Option(None, help="trained: ground truth, as --gt of `wiloc evaluate`.", rich_help_panel="trained inputs"),
    train_gt_map: Optional[str] = typer.Option(None, help="trained: the training map's positions CSV (positions form).", rich_help_panel="trained inputs"),
    train_tolerance: int = typer.Option(2, help="trained: +-frames for aligned or pairs ground truth.", rich_help_panel="trained inputs"),
    train_radius: Optional[float] = typer.Option(None, help="trained: metres, for positions ground truth.", rich_help_panel="trained inputs"),
    names: Optional[Path] = typer.Option(None, help="A .npy QUERY matrix: its frame names, one per line."),
    map_names: Optional[Path] = typer.Option(None, help="A .npy --map matrix: its frame names, one per line."),
    odometry: Optional[Path] = typer.Option(None, help="catgraph: query odometry CSV (name,distance or name,x,y).", rich_help_panel="catgraph inputs"),
    map_odometry: Optional[Path] = typer.Option(None, help="catgraph: reference odometry CSV.", rich_help_panel="catgraph inputs"),
    out_path: Optional[Path] = typer.Option(None, "--out", "-o", help="Results file (a folder with several queries)."),
    model_plot: Optional[Path] = typer.Option(None, help="online/trained: draw the learned histograms (the paper's Figure 1)."),
    cache: Optional[Path] = typer.Option(None, envvar="WILOC_CACHE", help="Cache folder."),
    jobs: Optional[int] = typer.Option(None, "--jobs", "-j", help="Worker processes for describing."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables (with --follow: one JSON line per frame)."),
    every: EveryOption = 1,
    fps: FpsOption = None,
    start: StartOption = "0",
    stop: StopOption = None,
    follow: bool = typer.Option(False, "--follow", help="Decide the frames already in the QUERY folder, then each new one as it arrives; rerun to resume.", rich_help_panel="live"),
    idle: Optional[float] = typer.Option(None, min=0.0, help="With --follow: stop after this many seconds without a new frame (default: run until Ctrl-C).", rich_help_panel="live"),
    method_options: Optional[dict[str, Any]] = None,
) -> None:
    """Decide, frame by frame, where each query frame was seen before and how sure that is.

    Example: wiloc localize data/day_left data/night_right --map data/day_right --method online

    Live: wiloc localize camera/ --map data/day_right --method catgraph --follow --idle 30
    """
    from wiloc.cache import Cache
    method_class(method)
    params = method_params(method, method_options or {})
    train_inputs = (train_query, train_map, train_gt)
    training = None
    if any(train_inputs):
        if not all(train_inputs):
            _fail("--train-query, --train-map and --train-gt go together", 2)
        training = api.Training(train_query, train_map,
                                _truth_source(train_gt, train_gt_map, train_tolerance, train_radius))
    sampling = api.Sampling(every=every, fps=fps, start=start, stop=stop)
    if follow:
        given = [flag for flag, value in (("--odometry", odometry), ("--names", names), ("--map-names", map_names),
                                          ("--metric", metric), ("--model-plot", model_plot)) if value is not None]
        given += ["video sampling"] * (sampling != api.Sampling())
        if len(queries) != 1 or given:
            _fail(f"--follow takes one query folder{' and not ' + ', '.join(given) if given else ''}", 2)
        _follow(queries[0], api.follow_folder(
            queries[0], reference=reference, descriptor=descriptor,
            descriptor_params=_descriptor_params(descriptor, crop, vocabulary, cache), method=method, method_params=params,
            exclude_recent=exclude_recent, training=training, map_odometry=map_odometry,
            out=out_path / api.results_name(queries[0], method, descriptor) if out_path is not None and out_path.is_dir() else out_path,
            cache=Cache(cache), jobs=jobs, idle=idle), as_json)
        return
    if idle is not None:
        _fail("--idle goes with --follow", 2)
    out_folder = out_path is not None and (out_path.is_dir() or not out_path.suffix)
    if len(queries) > 1 and out_path is not None and not out_folder:
        _fail(f"{out_path}: with several queries --out names a folder", 2)
    if model_plot is not None and method not in ("online", "trained"):
        _fail(f"{model_plot}: method '{method}' learns no histogram model to draw", 2)
    if out_path is not None and not out_folder:
        targets = [out_path]
    else:
        targets = [(out_path or Path.cwd()) / api.results_name(q, method, descriptor, metric) for q in queries]
    clash = next((t for t in targets if targets.count(t) > 1), None)
    if clash is not None:
        _fail(f"{clash}: two queries would write the same results file; give each its own --out", 2)
    store = Cache(cache)
    runs = []
    with progress_bar(not as_json) as progress:
        for query, target in zip(queries, targets):
            runs.append(api.localize(query, reference=reference, descriptor=descriptor, sampling=sampling,
                                     descriptor_params=_descriptor_params(descriptor, crop, vocabulary, cache),
                                     metric=metric, method=method, method_params=params,
                                     exclude_recent=exclude_recent, training=training,
                                     odometry=odometry, map_odometry=map_odometry,
                                     query_names_file=names, ref_names_file=map_names, out=target,
                                     cache=store, jobs=jobs, progress=progress))
    rows = []
    for run in runs:
        d = run.decisions
        conf = d.confidence[d.decided]
        rows.append({"query": run.query.name, "method": run.method, "frames": len(d),
                     "decided": int(d.decided.sum()),
                     "median confidence": float(sorted(conf)[len(conf) // 2]) if len(conf) else float("nan"),
                     "seconds": round(run.seconds, 2), "results": str(run.path)})
    if model_plot is not None:
        from wiloc.plots import plot_model
        plot_model(runs[0].decisions.model, model_plot, title=f"{runs[0].query.name} ({method})")
    skipped = list(dict.fromkeys(item for run in runs for item in run.skipped))
    replaced = [f"replaced the existing results file {run.path}" for run in runs if run.replaced]
    if as_json:
        _print_json([{**row, "skipped": [list(item) for item in run.skipped],
                      "warnings": [f"replaced the existing results file {run.path}"] if run.replaced else []}
                     for row, run in zip(rows, runs)])
    else:
        for path, reason in skipped:
            _note("skipped", f"{path}: {reason}")
        for line in replaced:
            _note("note", line)
        out.print(_table("localize", rows))
        if model_plot is not None:
            out.print(f"model plot: {model_plot}")


def _follow(query: Path, run: api.FollowRun, as_json: bool) -> None:
    """Render a followed run: a live table on a terminal, else one line (or JSON line) per frame."""
    from collections import deque

    from rich.live import Live

    from wiloc.methods.base import Decision

    started, decided = time.perf_counter(), 0
    latest: deque[Decision] = deque(maxlen=10)

    def view() -> Table:
        rate = decided / max(time.perf_counter() - started, 1e-9)
        table = Table(title=f"following {query} -> {run.path}",
                      caption=f"{run.resumed + decided} frames ({run.resumed} resumed), {rate:.1f} frames/s; Ctrl-C stops")
        for column in ("frame", "match", "confidence", "P(new place)", "stage"):
            table.add_column(column, justify="left" if column in ("frame", "match", "stage") else "right")
        for d in latest:
            table.add_row(d.frame, d.match_name or "-", _cell(d.confidence), _cell(d.new_place), d.stage)
        return table

    live = Live(view(), console=out, auto_refresh=False) if out.is_terminal and not as_json else None
    with live if live is not None else contextlib.nullcontext():
        for event in run:
            if isinstance(event, Decision):
                decided += 1
                latest.append(event)
                if live is not None:
                    live.update(view(), refresh=True)
                elif as_json:
                    print(json.dumps(_json_ready({"frame": event.frame, "match": event.match_name,
                                                  "confidence": event.confidence, "new_place": event.new_place,
                                                  "stage": event.stage})), flush=True)
                else:
                    print(f"{event.frame}\t{event.match_name or '-'}\t{_cell(event.confidence)}\t"
                          f"{_cell(event.new_place)}\t{event.stage}", flush=True)
            else:
                _note("skipped", f"{event.path}: {event.reason}")


# ------------------------------------------------------------------------------------------ evaluate

def _truth_source(gt: str, gt_ref: str | None, tolerance: int, radius: float | None) -> api.TruthSource:
    """`--gt` is a form name (aligned) or KIND:PATH (positions:q.csv, pairs:p.csv, matrix:m.npy),
    or a path whose suffix tells the form."""
    kind, sep, path = gt.partition(":")
    if not sep:
        if gt != "aligned" and not Path(gt).is_file() and "{query}" not in gt:
            _fail(f"--gt {gt}: neither a ground-truth form nor a file (forms: aligned, positions:Q.csv, "
                  "pairs:P.csv, matrix:M.npy)", 2)
        kind, path = ("aligned", "") if gt == "aligned" else (_guess_kind(gt), gt)
    if kind not in ("aligned", "positions", "pairs", "matrix"):
        _fail(f"--gt {gt}: unknown ground-truth form '{kind}' (aligned, positions, pairs, matrix)", 2)
    variable = None
    if kind == "matrix" and ".mat:" in path:
        path, variable = path.rsplit(":", 1)
    return api.TruthSource(kind=kind, path=path or None, ref_path=gt_ref, tolerance=tolerance, radius=radius,
                           variable=variable)


def _guess_kind(path: str) -> str:
    return "matrix" if Path(path).suffix.lower() in (".npy", ".mat") else "pairs"


GT_HELP = ("Ground truth: 'aligned' (same file name, +-tolerance frames), 'positions:Q.csv' (with "
           "--gt-map R.csv), 'pairs:P.csv' or 'matrix:M.npy|.csv|.mat' ('matrix:M.mat:NAME' picks one array of a .mat). '{query}' in a path is "
           "replaced by the query folder's name.")
GtOption = Annotated[str, typer.Option("--gt", help=GT_HELP)]
GtMapOption = Annotated[Optional[str], typer.Option("--gt-map", help="positions: the reference's positions CSV.")]
ToleranceOption = Annotated[int, typer.Option("--tolerance", "-T", min=0, help="aligned: same place within +-T frames (published evaluations use 2).")]
RadiusOption = Annotated[Optional[float], typer.Option("--radius", help="positions: same place within this many metres.")]
CutsOption = Annotated[str, typer.Option("--cuts", help="Confidence cuts for precision and recall at a fixed "
                                                        "cut, comma-separated, each in [0, 1].")]
CalibrationPlotOption = Annotated[Optional[Path], typer.Option(
    "--calibration-plot", help="Draw the reliability diagram (share correct against confidence).")]
CUTS_TEXT = ",".join(f"{cut:g}" for cut in DEFAULT_CUTS)


def _parse_cuts(text: str) -> list[float]:
    """`--cuts 0.5,0.9,0.99`: numbers in [0, 1]; anything else is a usage error."""
    try:
        cuts = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        cuts = []
    if not cuts or not all(0.0 <= cut <= 1.0 for cut in cuts):
        _fail(f"--cuts {text}: give confidences in [0, 1], comma-separated, such as {CUTS_TEXT}", 2)
    return cuts


@app.command()
@handles_errors
def evaluate(
    results: list[Path] = typer.Argument(..., help="Results files written by `wiloc localize`."),
    gt: GtOption = "aligned",
    gt_map: GtMapOption = None,
    tolerance: ToleranceOption = 2,
    radius: RadiusOption = None,
    pr_plot: Optional[Path] = typer.Option(None, help="Draw the precision-recall curves."),
    calibration_plot: CalibrationPlotOption = None,
    cuts: CutsOption = CUTS_TEXT,
    csv_out: Optional[Path] = typer.Option(None, "--csv", help="Write metrics (and curves beside it) as CSV."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Precision-recall and calibration of results files against ground truth.

    Example: wiloc evaluate day_left-online.csv --gt aligned --tolerance 2 --pr-plot pr.png --cuts 0.9,0.99
    """
    at = _parse_cuts(cuts)
    source = _truth_source(gt, gt_map, tolerance, radius)
    evaluations = [api.evaluate(path, source, at) for path in results]
    heads = [{"results": e.name, "method": e.method, "traversal": e.traversal, **e.summary.as_dict()}
             for e in evaluations]
    rows = [{**head, **e.calibration.row()} for head, e in zip(heads, evaluations)]
    if pr_plot is not None:
        from wiloc.plots import plot_pr
        plot_pr(dict(zip(api.run_names(evaluations), (e.curve for e in evaluations))), pr_plot)
    if calibration_plot is not None:
        from wiloc.plots import plot_reliability
        plot_reliability(api.reliability_series(evaluations), calibration_plot)
    if csv_out is not None:
        _write_metrics_csv(csv_out, rows, evaluations)
    if as_json:
        _print_json([{**head, "ground_truth": source.describe(), **e.calibration.as_dict(), "warnings": e.truth.warnings,
                      "curve": {"precision": e.curve.precision.tolist(), "recall": e.curve.recall.tolist(),
                                "thresholds": e.curve.thresholds.tolist()}}
                     for head, e in zip(heads, evaluations)])
        return
    _warn_about_truth(evaluations)
    out.print(metrics_view(rows, at, source.describe()))
    for path in (pr_plot, calibration_plot, csv_out):
        if path is not None:
            out.print(f"wrote {path}")


METRIC_LABELS = {"recall_at_100": "recall at 100 % precision", "recall_at_99": "recall at 99 % precision",
                 "recall_at_90": "recall at 90 % precision", "auc": "area under PR curve", "max_f1": "max F1",
                 "max_f1_threshold": "threshold at max F1", "recall_at_1": "R@1 (best match right)",
                 "frames": "frames", "decided": "decided frames", "with_true_match": "frames with a true match",
                 "ece": "ECE", "brier": "Brier score", "mean_confidence": "mean confidence",
                 "share_correct": "share correct"}


CUT_CAPTION = "at a cut: P precision, R recall, n frames accepted (decided, confidence >= cut)"


def _at_cut(row: dict[str, Any], cut: float) -> str:
    """Precision, recall and accepted frames at one confidence cut of a table row, one a line."""
    return f"P {_cell(row[f'precision@{cut:g}'])}\nR {_cell(row[f'recall@{cut:g}'])}\nn {row[f'accepted@{cut:g}']}"


def metrics_view(rows: list[dict[str, Any]], cuts: list[float], ground_truth: str) -> Table:
    """Metrics down, one column per results file: stays readable in 80 columns for a few runs."""
    table = Table(title=f"evaluate (ground truth: {ground_truth})", caption=CUT_CAPTION)
    table.add_column("")
    for row in rows:
        table.add_column(f"{row['method']}\n{row['traversal']}", justify="right")
    table.add_row("results", *[row["results"] for row in rows])
    for key, label in METRIC_LABELS.items():
        table.add_row(label, *[_cell(row[key]) for row in rows])
    for cut in cuts:
        table.add_row(f"cut {cut:g}", *[_at_cut(row, cut) for row in rows])
    return table


def _warn_about_truth(evaluations: list[api.Evaluation]) -> None:
    """Name-matching warnings, and runs whose ground truth leaves nothing to recall."""
    for e in evaluations:
        for warning in e.truth.warnings:
            _note("warning", f"{e.path}: {warning}")
        if not e.truth.has_match().any():
            _note("warning", f"{e.path}: no frame has a true match under this ground truth, so every "
                             "recall is 0 (check --gt, --tolerance, --radius)")


def _write_metrics_csv(path: Path, rows: list[dict[str, Any]], evaluations: list[api.Evaluation]) -> None:
    import pandas as pd
    pd.DataFrame(rows).to_csv(path, index=False)
    curves = pd.concat([pd.DataFrame({"results": e.name, "threshold": e.curve.thresholds,
                                      "precision": e.curve.precision, "recall": e.curve.recall})
                        for e in evaluations])
    curves.to_csv(path.with_name(path.stem + "-curves.csv"), index=False)


# ------------------------------------------------------------------------------------------- compare

@app.command()
@handles_errors
def compare(
    results: list[Path] = typer.Argument(..., help="Results files: several methods x query traversals."),
    gt: GtOption = "aligned",
    gt_map: GtMapOption = None,
    tolerance: ToleranceOption = 2,
    radius: RadiusOption = None,
    global_threshold: bool = typer.Option(True, "--global-threshold/--no-global-threshold",
                                          help="Table II: one threshold per method for all traversals."),
    precision: str = typer.Option("100,99", help="Table II target precisions in percent, comma-separated."),
    cuts: CutsOption = CUTS_TEXT,
    threshold_plot: Optional[Path] = typer.Option(None, help="Precision against normalised threshold (the paper's Figure 5)."),
    model_plot: Optional[Path] = typer.Option(None, help="Learned histograms of the first online run (Figure 1)."),
    pr_plot: Optional[Path] = typer.Option(None, help="All precision-recall curves."),
    calibration_plot: CalibrationPlotOption = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Methods and traversals side by side: the paper's Table I, calibration at fixed cuts, Table II.

    Example: wiloc compare *-online.csv *-threshold.csv --gt aligned -T 2 --precision 100,99
    """
    try:
        targets = [float(p) for p in precision.split(",") if p.strip()]
    except ValueError:
        _fail(f"--precision {precision}: give percentages such as 100,99.5", 2)
    at = _parse_cuts(cuts)
    source = _truth_source(gt, gt_map, tolerance, radius)
    comparison = api.compare(results, source, precisions=targets, global_thresholds=global_threshold, cuts=at)
    _warn_about_truth(comparison.evaluations)
    written = _compare_plots(comparison, threshold_plot, model_plot, pr_plot, calibration_plot)
    if as_json:
        calibration = [{"method": label, "traversal": traversal, **e.calibration.as_dict()} for label, traversal, e
                       in zip(comparison.labels, comparison.traversals, comparison.evaluations)]
        _print_json({"ground_truth": comparison.ground_truth,
                     "table1": comparison.table1.to_dict(orient="records"), "calibration": calibration,
                     "table2": comparison.table2.to_dict(orient="records"), "plots": [str(p) for p in written]})
        return
    out.print(table1_view(comparison))
    for table in cut_views(comparison, at):
        out.print(table)
    if global_threshold:
        out.print(table2_view(comparison))
    for path in written:
        out.print(f"wrote {path}")


def _compare_plots(comparison: api.Comparison, threshold_plot: Path | None, model_plot: Path | None,
                   pr_plot: Path | None, calibration_plot: Path | None) -> list[Path]:
    from wiloc import plots
    written = []
    if threshold_plot is not None:
        plots.plot_threshold(api.threshold_series(comparison), threshold_plot)
        written.append(threshold_plot)
    if model_plot is not None:
        learned = sorted((e for e in comparison.evaluations if e.method in ("online", "trained")),
                         key=lambda e: e.method != "online")
        if not learned:
            _fail(f"{model_plot}: none of the results is an online or trained run with a model", 1)
        plots.plot_model(learned[0].results.model, model_plot, title=f"{learned[0].method} {learned[0].traversal}")
        written.append(model_plot)
    if pr_plot is not None:
        plots.plot_pr(api.pr_series(comparison), pr_plot)
        written.append(pr_plot)
    if calibration_plot is not None:
        plots.plot_reliability(api.reliability_series(comparison.evaluations), calibration_plot)
        written.append(calibration_plot)
    return written


def cut_views(comparison: api.Comparison, cuts: list[float]) -> list[Table]:
    """Per traversal, one row per method: calibration and precision / recall at each fixed cut."""
    tables = []
    for traversal, group in comparison.cut_table.groupby("traversal", sort=False):
        table = Table(title=f"Calibration and fixed confidence cuts: {traversal} ({comparison.ground_truth})",
                      caption=CUT_CAPTION,
                      pad_edge=False)
        table.add_column("method", overflow="fold")
        for column in ("ECE", "Brier", "mean\nconf.", "share\ncorrect"):
            table.add_column(column, justify="right")
        for cut in cuts:
            table.add_column(f"cut\n{cut:g}")
        for row in group.to_dict(orient="records"):
            table.add_row(row["method"], *[_cell(row[key]) for key in ("ece", "brier", "mean_confidence",
                                                                         "share_correct")],
                          *[_at_cut(row, cut) for cut in cuts])
        tables.append(table)
    return tables


def table1_view(comparison: api.Comparison) -> Table:
    """Table I: recall at 100/99/90 % precision, one row per traversal, columns per method."""
    t1 = comparison.table1
    methods = list(dict.fromkeys(t1["method"]))
    table = Table(title=f"Table I: recall at 100 / 99 / 90 % precision (plus AUC, R@1); {comparison.ground_truth}")
    table.add_column("traversal")
    for m in methods:
        table.add_column(m, justify="right")
    for traversal in dict.fromkeys(t1["traversal"]):
        cells = []
        for m in methods:
            sel = t1[(t1["traversal"] == traversal) & (t1["method"] == m)]
            if sel.empty:
                cells.append("")
                continue
            r = sel.iloc[0]
            cells.append(f"{r['recall@100']:.1%} / {r['recall@99']:.1%} / {r['recall@90']:.1%}\n"
                         f"AUC {r['auc']:.3f}  R@1 {r['R@1']:.3f}")
        table.add_row(traversal, *cells)
    return table


def table2_view(comparison: api.Comparison) -> Table:
    """Table II: the global threshold per method and precision, recall per traversal, worst marked."""
    t2 = comparison.table2
    traversals = list(dict.fromkeys(t2["traversal"]))
    table = Table(title=f"Table II: one global threshold per method (worst traversal marked *); {comparison.ground_truth}")
    for column in ("method", "precision", "threshold", *traversals):
        table.add_column(column, justify="left" if column == "method" else "right")
    for (method, target), group in t2.groupby(["method", "precision"], sort=False):
        cells = {row.traversal: f"{row.recall:.1%}{' *' if row.worst else ''}" for row in group.itertuples()}
        threshold = group["threshold"].iloc[0]
        table.add_row(method, f"{target:g}%", _cell(float(threshold)), *[cells.get(t, "") for t in traversals])
    return table


# ---------------------------------------------------------------------------------------------- demo

@app.command()
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
        _print_json({"table1": report.comparison.table1.to_dict(orient="records"),
                     "table2": report.comparison.table2.to_dict(orient="records"),
                     "out": str(out_dir), "files": [str(p) for p in report.files]})
        return
    out.print(table1_view(report.comparison))
    out.print(table2_view(report.comparison))
    out.print(f"demo outputs in [bold]{out_dir}[/bold]: " + ", ".join(p.name for p in report.files))
