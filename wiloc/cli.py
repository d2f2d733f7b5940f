"""The `wiloc` command line: parse options, call wiloc.api, render rich tables or JSON.

This module loads quickly (``wiloc --help`` answers without pandas, scipy, h5py or OpenCV): the
commands import wiloc.api when they run. Shared machinery is in wiloc.cli_core (errors, parsing)
and wiloc.cli_views (tables, JSON, progress).
"""
from __future__ import annotations

import contextlib
import json
import os
import time
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer
from rich.table import Table

from wiloc import __version__
from wiloc.atomic import written_whole
from wiloc.candidates import DEFAULT_EXCLUDE_RECENT, RANKED
from wiloc.cli_core import Command, CommandLine, Notes, error, fail, handles_errors, note, out, refuse_unused
from wiloc.cli_params import (descriptor_params, descriptor_takers, descriptor_uses, method_params,
                              with_descriptor_options, with_method_options)
from wiloc.cli_views import (cell, comparison_records, cut_views, json_ready, metrics_views, new_place_view,
                             print_command_json, progress_bar, run_records, table, table1_view, table2_view)
from wiloc.errors import EXIT_BAD_INPUT, EXIT_USAGE, WilocError
from wiloc.labels import short_names
from wiloc.methods.registry import METHODS, method_class
from wiloc.metrics import RANKED_KS
from wiloc.reliability import DEFAULT_CUTS

if TYPE_CHECKING:
    from wiloc import api

# FFmpeg inside OpenCV reads its log level once, when cv2 is loaded: keep its lines about damaged
# videos ("[mpeg4 @ 0x...] header damaged") off the terminal, since wiloc reports them itself.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET

app = typer.Typer(
    name="wiloc", cls=CommandLine, add_completion=False, no_args_is_help=True, rich_markup_mode="rich",
    help="Appearance-based localization with whole-image descriptors and a probability model "
         "learned online.\n\nExample: [bold]wiloc demo[/bold], then\n\n"
         "  wiloc localize data/day_left --map data/day_right --descriptor sad --method online")


def run(args: list[str] | None = None) -> int:
    """Run the command line on ``args`` (default: the process's) and return its exit code."""
    return typer.main.get_command(app).main(args, prog_name="wiloc", standalone_mode=False)


def _version(value: bool) -> None:
    if value:
        out.print(f"wiloc {__version__}")
        raise typer.Exit()


@app.callback()
def main(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                      help="Print the version and exit.")) -> None:
    """wiloc: have I been here before, where, and how sure am I?"""


def _output_file(value: Path | None) -> Path | None:
    """An output file option (``--csv``, ``--out FILE.csv``, a plot), checked as the options are
    read, before any work: its folder must exist (a typo is not made into new folders; folders
    that ``--out`` names are created)."""
    if value is not None and value.suffix and not value.is_dir() and not value.parent.is_dir():
        raise typer.BadParameter(f"the folder {value.parent} does not exist (create it first)")
    return value


def _plot_file(value: Path | None) -> Path | None:
    """A plot option's file, checked as the options are read, before any work: its folder must
    exist, its suffix name a format the figures can be written in."""
    if _output_file(value) is not None:
        from wiloc.plots import check_plot_path
        try:
            check_plot_path(value)
        except WilocError as exc:
            raise typer.BadParameter(exc.problem) from None
    return value


def _descriptor_params(descriptor: str, options: dict[str, Any] | None, vocabulary: str | None, cache: Path | None,
                       model: Path | None = None, preprocess: list[str] | None = None) -> dict[str, Any]:
    """The descriptor parameters the command line sets: its options typed (and those always
    passed), a vocabulary ``file`` from --vocabulary (needed by a descriptor taking one), a
    ``model`` from --model (likewise) with --preprocess KEY=VALUE. A descriptor that is not built
    in comes from a plugin: plugins that failed to load are warned of."""
    from wiloc.descriptors.registry import BUILT_IN, DESCRIPTORS, plugin_problems

    if descriptor not in DESCRIPTORS or DESCRIPTORS[descriptor].source != BUILT_IN:
        for problem in plugin_problems():
            note("warning", problem)
    params = descriptor_params(descriptor, options or {})
    if descriptor in descriptor_takers("file"):
        if vocabulary is None:
            fail(f"--vocabulary: --descriptor {descriptor} needs one (a file, or a key from `wiloc vocabulary`)",
                 EXIT_USAGE)
        from wiloc import api
        from wiloc.cache import Cache
        params["file"] = str(api.vocabulary_file(vocabulary, Cache(cache)))
    if descriptor in descriptor_takers("model"):
        if model is None:
            fail(f"--model: --descriptor {descriptor} needs one (an .onnx model file)", EXIT_USAGE)
        params.update({"model": str(model), **_preprocess_options(preprocess or [])})
    return params


def _preprocess_options(items: list[str]) -> dict[str, str]:
    """`--preprocess KEY=VALUE` options as {key: value text}, keys those of the model metadata."""
    from wiloc.descriptors.learned import KEYS

    options = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key.strip() not in KEYS:
            fail(f"--preprocess: '{item}': give KEY=VALUE, KEY one of {', '.join(KEYS)}", EXIT_USAGE)
        options[key.strip()] = value.strip()
    return options


DescriptorOption = Annotated[str, typer.Option(
    "--descriptor", "-d", help="sad | gist | brisk-gist | bow (with --vocabulary; fabmap and catgraph then read "
                               "FAB-MAP's evidence) | onnx (with --model) | a plugin's (describe --list-descriptors)")]
ModelOption = Annotated[Optional[Path], typer.Option(
    "--model", help="onnx: the network, an .onnx file (docs/descriptors.md, Learned descriptors).")]
PreprocessOption = Annotated[Optional[list[str]], typer.Option(
    "--preprocess", metavar="KEY=VALUE", show_default="the model's metadata",
    help="onnx: input_size=224x224, resize=stretch|crop, mean=R,G,B, std=R,G,B, colour=rgb|bgr, "
         "normalise=true|false; repeat for several.")]
VocabularyOption = Annotated[Optional[str], typer.Option(
    help="bow: the vocabulary (its file, or its key in the cache) from `wiloc vocabulary`.")]
CacheOption = Annotated[Optional[Path], typer.Option(envvar="WILOC_CACHE", show_default="the per-user cache folder",
                                                     help="Cache folder.")]
JobsOption = Annotated[Optional[int], typer.Option("--jobs", "-j", show_default="all cores",
                                                   help="Worker processes for describing image folders (onnx: threads).")]
STREAMS = "video files and ROS bags"
EveryOption = Annotated[int, typer.Option(help="Videos, bags: every K-th frame of the cut.", rich_help_panel=STREAMS)]
FpsOption = Annotated[Optional[float], typer.Option(
    show_default="every frame, as --every", rich_help_panel=STREAMS,
    help="Videos, bags: about F frames per second (by timestamp), instead of --every.")]
StartOption = Annotated[str, typer.Option(help="Videos, bags: first frame, an index (120) or seconds (12.5s).",
                                          rich_help_panel=STREAMS)]
StopOption = Annotated[Optional[str], typer.Option(help="Videos, bags: end of the cut (excluded), an index or seconds.",
                                                   show_default="the end", rich_help_panel=STREAMS)]
TopicOption = Annotated[Optional[str], typer.Option(
    show_default="the bag's only image topic", rich_help_panel=STREAMS,
    help="ROS bags: the image topic (sensor_msgs Image or CompressedImage), such as /camera/image_raw.")]
SchedulerOption = Annotated[Optional[str], typer.Option(
    envvar="WILOC_SCHEDULER", show_default="none: this machine",
    help="Dask scheduler address (tcp://host:8786), or 'local' for a local cluster of --jobs workers; "
         "needs the optional dask extra (docs/scaling.md).")]
SAMPLING = ("every", "fps", "start", "stop")


# ------------------------------------------------------------------------------------------ describe

@app.command(cls=Command)
@handles_errors
@with_descriptor_options
def describe(
    folders: list[Path] = typer.Argument(None, metavar="FOLDER...", show_default=False,
                                         help="Image folders, video files or ROS bags (one traversal each)."),
    descriptor: DescriptorOption = "sad",
    vocabulary: VocabularyOption = None,
    model: ModelOption = None,
    preprocess: PreprocessOption = None,
    import_file: Optional[Path] = typer.Option(None, "--import", help="External descriptors: an N x D matrix (.npy, .csv, .h5), hloc's global-feats-*.h5, or a folder of per-image .npy files (with --out)."),
    names: Optional[Path] = typer.Option(None, help="With --import .npy: text file of frame names, one a line."),
    metric: Optional[str] = typer.Option(None, show_default="the file's recorded metric, else l1", help="With --import: l1 | sqeuclidean | hamming | cosine"),
    import_out: Optional[Path] = typer.Option(None, "--out", "-o", callback=_output_file, show_default="none: only the cache",
                                              help="With --import: write the descriptors to FILE.h5 with their names and metric, so that localize and evaluate take FILE.h5 alone."),
    prefix: str = typer.Option("", show_default="none: every frame", help="With --import --out: keep only the frames whose names begin with this (hloc's db/ or query/), dropping it from the names."),
    every: EveryOption = 1,
    fps: FpsOption = None,
    start: StartOption = "0",
    stop: StopOption = None,
    topic: TopicOption = None,
    list_cache: bool = typer.Option(False, "--list", help="Show what the cache holds."),
    list_descriptors: bool = typer.Option(False, "--list-descriptors",
                                          help="Show the descriptors there are: built in, or from installed plugins."),
    cache: CacheOption = None,
    jobs: JobsOption = None,
    scheduler: SchedulerOption = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
    descriptor_options: Optional[dict[str, Any]] = None,
) -> None:
    """Compute whole-image descriptors of image folders, video files or ROS bags into the HDF5 cache.

    Example: wiloc describe data/gardens-point-walking/day_right --descriptor gist
    """
    from wiloc import api
    from wiloc.cache import Cache

    importing = import_file is not None
    if list_cache and (folders or importing):
        fail("--list: shows what the cache holds; give it no FOLDER and no --import", EXIT_USAGE)
    if list_descriptors:
        if folders or importing or list_cache:
            fail("--list-descriptors: shows the descriptors there are; give it no FOLDER, --import or --list",
                 EXIT_USAGE)
        _list_descriptors(as_json)
        return
    refuse_unused({"descriptor": (not importing, "image folders and video files"),
                   **descriptor_uses(descriptor, described=not importing),
                   "metric": (importing, "--import"), "names": (importing, "--import"),
                   "import_out": (importing, "--import"), "prefix": (import_out is not None, "--import with --out"),
                   "jobs": (not importing, "image folders"),
                   **{name: (not importing, STREAMS) for name in (*SAMPLING, "topic")}})
    store = Cache(cache)
    if list_cache:
        _list_cache(store, as_json)
        return
    if not importing and not folders:
        fail("FOLDER...: give image folders, video files, ROS bags, --import FILE or --list", EXIT_USAGE)
    sampling = api.Sampling(every=every, fps=fps, start=start, stop=stop)
    with progress_bar(not as_json) as progress:
        if importing:
            reports = [api.import_descriptors(import_file, metric=metric, names=names, cache=store, out=import_out,
                                              prefix=prefix)]
        else:  # one call: the folders' frames form one stream over the workers
            reports = api.describe(folders, descriptor,
                                   descriptor_params=_descriptor_params(descriptor, descriptor_options, vocabulary, cache,
                                                                        model, preprocess),
                                   cache=store, jobs=jobs, progress=progress, sampling=sampling, scheduler=scheduler,
                                   topic=topic)
    rows, notes = [], []
    for label, r in zip(short_names([r.folder for r in reports]), reports):
        said = Notes()
        for line in (*r.repairs, *r.notes):
            said.add("note", line)
        for name, reason in r.failed if not r.video else ():
            said.add("skipped", f"{Path(r.folder) / name}: {reason}")
        if len(r.sizes) > 1:
            said.add("note", f"{r.folder}: images of {len(r.sizes)} different sizes")
        notes.append(said)
        rows.append({"folder": label, "descriptor": r.descriptor, "frames": r.frames,
                     "shape": list(r.shape), "computed": r.computed, "reused": r.reused,
                     "failed": len(r.failed), "images_per_second": r.images_per_second if r.computed else None})
    if as_json:
        print_command_json("describe", "results", [{**row, "folder": r.folder, "failed_frames": [list(f) for f in r.failed],
                                                    "ignored": list(r.ignored)} for row, r in zip(rows, reports)],
                           [line for said in notes for line in said])
    else:
        out.print(table("describe", [{**row, "shape": "x".join(map(str, row["shape"]))} for row in rows],
                        labels={"images_per_second": "images/s"}, digits={"images_per_second": 1}))
    # A video that stops decoding early is an error, after its good frames went into the cache.
    problems = [f"{r.folder}: {reason}" for r in reports if r.video for _, reason in r.failed]
    problems += [f"{r.folder}: no image could be described (see the lines above)"
                 for r in reports if r.entry.data.shape[0] == 0]
    for problem in problems:
        error(problem)
    if problems:
        raise typer.Exit(EXIT_BAD_INPUT)


def _list_cache(store: Any, as_json: bool) -> None:
    """`describe --list`: one row per cache entry, told apart by folder, descriptor and parameters."""
    infos = store.list_entries()
    if as_json:
        print_command_json("describe", "results", [asdict(info) for info in infos], [])
        return
    rows = [{"folder": label, "descriptor": info.descriptor, "params": _params_text(info.descriptor, info.params),
             "frames": info.frames, "complete": info.complete, "MB": info.size / 1e6,
             "updated": info.updated[:10], "problem": info.problem}
            for label, info in zip(short_names([i.folder for i in infos]), infos)]
    columns = ["folder", "descriptor", "params", "frames", "complete", "MB"]  # --json: when each was updated
    out.print(table(f"cache {store.root}", rows, columns + ["problem"] * any(i.problem for i in infos),
                    labels={"complete": "done"}, digits={"MB": 1},
                    caption="params: those that differ from the descriptor's defaults"))


def _list_descriptors(as_json: bool) -> None:
    """`describe --list-descriptors`: each descriptor, where it comes from, its metric and length;
    a plugin that failed to load is a warning line (and in --json, a warning)."""
    from wiloc.descriptors.registry import available_descriptors, plugin_problems

    notes = Notes()
    for problem in plugin_problems():
        notes.add("warning", problem)
    infos = available_descriptors()
    if as_json:
        print_command_json("describe", "results", [asdict(info) for info in infos], notes)
        return
    rows = [{"descriptor": info.name, "from": info.source, "metric": info.metric or f"by {info.depends}",
             "length": info.length if info.length is not None else f"by {info.depends}"} for info in infos]
    out.print(table("descriptors", rows, caption="plugins: packages registering the entry-point group "
                                                 "wiloc.descriptors (docs/descriptors.md)"))


def _params_text(descriptor: str, params: dict[str, Any]) -> str:
    """An entry's parameters as a table shows them: those that differ from the descriptor's
    defaults, a video's or bag's sampling and topic, an import's metric; never the content digests."""
    from wiloc.descriptors.registry import DESCRIPTOR_NAMES, get_descriptor

    defaults = get_descriptor(descriptor).params if descriptor in DESCRIPTOR_NAMES else {}
    parts = []
    for key, value in sorted(params.items()):
        if key == "sampling":
            parts += [f"{k}={v}" for k, v in value.items() if v is not None and (k, v) not in (("every", 1), ("start", 0), ("start", "0"))]
        elif value is not None and key not in ("video", "bag", "file_digest", "names_digest", "model_digest") \
                and defaults.get(key) != value:
            if key == "file" and "vocabulary" in params:
                continue  # a bow entry's vocabulary file: its key says which
            parts.append(f"{key}={Path(value).name if key in ('names', 'model') else value}")
    return ", ".join(parts) or "defaults"


# ---------------------------------------------------------------------------------------- vocabulary

@app.command(cls=Command)
@handles_errors
def vocabulary(
    folders: list[Path] = typer.Argument(..., metavar="FOLDER...", help="Training image folders (never the pair you will test on)."),
    feature: str = typer.Option("sift", help="Local feature: sift (k-means) or orb (k-majority)."),
    words: int = typer.Option(1000, help="K, the number of visual words."),
    max_features: int = typer.Option(500, help="Local features kept per image, strongest first."),
    max_side: int = typer.Option(640, help="Images are shrunk so their longer side is at most this many pixels."),
    iterations: int = typer.Option(25, help="At most this many clustering rounds."),
    seed: int = typer.Option(0, help="Seeds the initial centres."),
    cache: CacheOption = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Cluster the local features of training folders into a visual vocabulary for bow and FAB-MAP.

    The vocabulary is kept in the cache.

    Example: wiloc vocabulary data/night_right --words 1000, then
    wiloc localize data/day_left --map data/day_right --descriptor bow --vocabulary KEY --method fabmap
    """
    from wiloc import api
    from wiloc.cache import Cache

    params = {"feature": feature, "words": words, "max_features": max_features, "max_side": max_side,
              "iterations": iterations, "seed": seed}
    with progress_bar(not as_json) as progress:
        report = api.vocabulary(folders, params, cache=Cache(cache), progress=progress)
    notes = Notes()
    for path, reason in report.failed:
        notes.add("skipped", f"{path}: {reason}")
    sparse = report.vocabulary.too_few_words()
    if sparse is not None:
        notes.add("warning", sparse)
    row = {"key": report.vocabulary.key, "words": report.vocabulary.n_words,
           "training_frames": len(report.vocabulary.training_frames), "built": report.built,
           "seconds": report.seconds, "file": str(report.path)}
    if as_json:
        print_command_json("vocabulary", "results", [{**row, "failed": [list(item) for item in report.failed]}], notes)
        return
    out.print(table("vocabulary", [{**row, "file": report.path.name}], labels={"training_frames": "training\nframes"},
                    digits={"seconds": 1}, caption=f"in {report.path.parent}"))


# ------------------------------------------------------------------------------------------ localize

@app.command(cls=Command)
@handles_errors
@with_method_options
@with_descriptor_options
def localize(
    queries: list[Path] = typer.Argument(..., metavar="QUERY...",
                                         help="Query traversal folder(s) (or descriptor matrix files)."),
    reference: Optional[Path] = typer.Option(None, "--map", "-m", show_default="none: sequence mode",
                                             help="Reference traversal; omit for sequence mode (loop closure)."),
    descriptor: DescriptorOption = "sad",
    vocabulary: VocabularyOption = None,
    model: ModelOption = None,
    preprocess: PreprocessOption = None,
    metric: Optional[str] = typer.Option(None, show_default="the file's recorded metric", help="For descriptor matrix files: l1 | sqeuclidean | hamming | cosine"),
    method: str = typer.Option("online", help=" | ".join(METHODS)),
    exclude_recent: int = typer.Option(DEFAULT_EXCLUDE_RECENT, "--exclude-recent", "-R", help="Recent frames excluded as candidates (sequence mode) and around each map frame when learning from the map."),
    train_query: Optional[Path] = typer.Option(None, help="trained: labelled training query traversal.", rich_help_panel="trained inputs"),
    train_map: Optional[Path] = typer.Option(None, help="trained: its reference traversal.", rich_help_panel="trained inputs"),
    train_gt: Optional[str] = typer.Option(None, help="trained: ground truth, as --gt of `wiloc evaluate`.", rich_help_panel="trained inputs"),
    train_gt_map: Optional[str] = typer.Option(None, help="trained: the training map's positions CSV (positions form).", rich_help_panel="trained inputs"),
    train_tolerance: int = typer.Option(2, help="trained: +-frames for aligned ground truth.", rich_help_panel="trained inputs"),
    train_radius: Optional[float] = typer.Option(None, help="trained: metres, for positions ground truth.", rich_help_panel="trained inputs"),
    names: Optional[Path] = typer.Option(None, help="A .npy QUERY matrix: its frame names, one per line."),
    map_names: Optional[Path] = typer.Option(None, help="A .npy --map matrix: its frame names, one per line."),
    odometry: Optional[Path] = typer.Option(None, help="catgraph: query odometry CSV (name,distance or name,x,y).", rich_help_panel="catgraph inputs"),
    odometry_topic: Optional[str] = typer.Option(None, help="catgraph: the nav_msgs Odometry topic of the ROS bags (query and map).", rich_help_panel="catgraph inputs"),
    map_odometry: Optional[Path] = typer.Option(None, help="catgraph: reference odometry CSV.", rich_help_panel="catgraph inputs"),
    out_path: Optional[Path] = typer.Option(None, "--out", "-o", callback=_output_file, show_default="QUERY-DESCRIPTOR-METHOD.csv here",
                                            help="Results file (a folder with several queries)."),
    model_plot: Optional[Path] = typer.Option(None, callback=_plot_file, show_default="none: not drawn", help="online/trained: draw the learned histograms (the paper's Figure 1)."),
    cache: CacheOption = None,
    jobs: JobsOption = None,
    scheduler: SchedulerOption = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables (with --follow: one JSON line per frame)."),
    every: EveryOption = 1,
    fps: FpsOption = None,
    start: StartOption = "0",
    stop: StopOption = None,
    topic: TopicOption = None,
    follow: bool = typer.Option(False, "--follow", help="Decide the frames already in the QUERY folder, then each new one as it arrives; rerun to resume.", rich_help_panel="live"),
    idle: Optional[float] = typer.Option(None, min=0.0, show_default="run until Ctrl-C", help="With --follow: stop after this many seconds without a new frame.", rich_help_panel="live"),
    method_options: Optional[dict[str, Any]] = None,
    descriptor_options: Optional[dict[str, Any]] = None,
) -> None:
    """Decide, frame by frame, where each query frame was seen before and how sure that is.

    Example: wiloc localize data/day_left data/night_right --map data/day_right --method online

    Live: wiloc localize camera/ --map data/day_right --method catgraph --follow --idle 30
    """
    from wiloc import api
    from wiloc.cache import Cache
    from wiloc.traversals import is_matrix_file

    method_class(method)
    params = method_params(method, method_options or {})
    matrices = [is_matrix_file(Path(p)) for p in (*queries, reference, train_query, train_map) if p is not None]
    refuse_unused({"descriptor": (not all(matrices), "image folders and video files"),
                   **descriptor_uses(descriptor, described=not all(matrices)),
                   "metric": (any(matrices), "descriptor matrix files (.npy, .csv, .h5)"),
                   "names": (any(is_matrix_file(q) for q in queries), "a descriptor matrix file as QUERY"),
                   "map_names": (reference is not None and is_matrix_file(reference),
                                 "a descriptor matrix file as --map")})
    train_inputs = (train_query, train_map, train_gt)
    refuse_unused({name: (any(train_inputs), "a training pair (--train-query, --train-map, --train-gt)")
                   for name in ("train_gt_map", "train_tolerance", "train_radius")})
    training = None
    if any(train_inputs):
        if not all(train_inputs):
            fail("--train-query, --train-map and --train-gt go together", EXIT_USAGE)
        training = api.Training(train_query, train_map,
                                _truth_source(train_gt, train_gt_map, train_tolerance, train_radius, prefix="train_"))
    sampling = api.Sampling(every=every, fps=fps, start=start, stop=stop)
    if follow:
        given = [flag for flag, value in (("--odometry", odometry), ("--odometry-topic", odometry_topic),
                                          ("--topic", topic), ("--names", names), ("--map-names", map_names),
                                          ("--metric", metric), ("--model-plot", model_plot)) if value is not None]
        given += ["video sampling"] * (sampling != api.Sampling())
        if len(queries) != 1 or given:
            fail(f"--follow takes one query folder{' and not ' + ', '.join(given) if given else ''}", EXIT_USAGE)
        _follow(queries[0], api.follow_folder(
            queries[0], reference=reference, descriptor=descriptor,
            descriptor_params=_descriptor_params(descriptor, descriptor_options, vocabulary, cache, model, preprocess),
            method=method, method_params=params,
            exclude_recent=exclude_recent, training=training, map_odometry=map_odometry,
            out=out_path / api.results_name(queries[0], method, descriptor) if out_path is not None and out_path.is_dir() else out_path,
            cache=Cache(cache), jobs=jobs, idle=idle), as_json)
        return
    if idle is not None:
        fail("--idle goes with --follow", EXIT_USAGE)
    out_folder = out_path is not None and (out_path.is_dir() or not out_path.suffix)
    if len(queries) > 1 and out_path is not None and not out_folder:
        fail(f"{out_path}: with several queries --out names a folder", EXIT_USAGE)
    if model_plot is not None and method not in ("online", "trained"):
        fail(f"{model_plot}: method '{method}' learns no histogram model to draw", EXIT_USAGE)
    if out_path is not None and not out_folder:
        targets = [out_path]
    else:
        targets = [(out_path or Path.cwd()) / api.results_name(q, method, descriptor, metric) for q in queries]
    clash = next((t for t in targets if targets.count(t) > 1), None)
    if clash is not None:
        fail(f"{clash}: two queries would write the same results file; give each its own --out", EXIT_USAGE)
    store = Cache(cache)
    runs, repairs = [], []
    with progress_bar(not as_json) as progress:
        for query, target in zip(queries, targets):
            known = len(store.repairs)
            runs.append(api.localize(query, reference=reference, descriptor=descriptor, sampling=sampling,
                                     descriptor_params=_descriptor_params(descriptor, descriptor_options, vocabulary,
                                                                          cache, model, preprocess),
                                     metric=metric, method=method, method_params=params,
                                     exclude_recent=exclude_recent, training=training,
                                     odometry=odometry, map_odometry=map_odometry,
                                     query_names_file=names, ref_names_file=map_names, out=target,
                                     cache=store, jobs=jobs, progress=progress, scheduler=scheduler,
                                     topic=topic, odometry_topic=odometry_topic))
            repairs.append(store.repairs[known:])
    shown = set()
    rows, notes = [], []
    for label, run, repaired in zip(short_names([r.query for r in runs]), runs, repairs):
        said = Notes()
        for line in (*repaired, *(line for line in run.notes if ("note", line) not in shown)):
            said.add("note", line)
            shown.add(("note", line))
        for path, reason in run.skipped:
            if (path, reason) not in shown:
                said.add("skipped", f"{path}: {reason}")
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
                     "median_confidence": float(sorted(conf)[len(conf) // 2]) if len(conf) else float("nan"),
                     "seconds": run.seconds, "results": run.path.name})
    if model_plot is not None:
        from wiloc.plots import plot_model
        plot_model(runs[0].decisions.model, _replacing(notes[0], model_plot), title=f"{runs[0].query.name} ({method})")
    if as_json:
        print_command_json("localize", "runs", [
            {**row, "descriptor": run.results.meta.get("descriptor"), "traversal": row["query"],
             "query": str(run.query.resolve()), "results": str(run.path.resolve()),
             "skipped": [list(item) for item in run.skipped]} for row, run in zip(rows, runs)],
            [line for said in notes for line in said])
        return
    for row in rows:
        row["decided"] = f"{row['decided']}/{row.pop('frames')}"
    folders = ", ".join(dict.fromkeys(str(run.path.parent) for run in runs))
    out.print(table("localize", rows, ["query", "method", "decided", "median_confidence", "results"],
                    labels={"median_confidence": "median\nconf."},
                    caption=f"results in {folders}; {sum(run.seconds for run in runs):.1f} s"))
    if model_plot is not None:
        out.print(f"wrote {model_plot}")


FOLLOW_COLUMNS = ("frame", "match", "confidence", "P(new place)", "stage")


def _follow(query: Path, run: api.FollowRun, as_json: bool) -> None:
    """Render a followed run: a live table on a terminal, else a header line and one line (or
    JSON line) per frame, and when ``--idle`` ends the run a last line saying so; a frame left out
    is a note on stderr (with --json also a line ``{"warnings": [...]}``)."""
    from collections import deque

    from rich.live import Live

    from wiloc.methods.base import Decision

    started, decided = time.perf_counter(), 0
    latest: deque[Decision] = deque(maxlen=10)
    notes = Notes()

    def view() -> Table:
        rate = decided / max(time.perf_counter() - started, 1e-9)
        live_table = Table(title=cell(f"following {query} -> {run.path}"),
                           caption=f"{run.resumed + decided} frames ({run.resumed} resumed), {rate:.1f} frames/s; Ctrl-C stops")
        for column in FOLLOW_COLUMNS:
            live_table.add_column(column, justify="left" if column in ("frame", "match", "stage") else "right")
        for d in latest:
            live_table.add_row(cell(d.frame), cell(d.match_name), cell(d.confidence), cell(d.new_place), d.stage)
        return live_table

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
                    print(f"{event.frame}\t{event.match_name or '-'}\t{cell(event.confidence)}\t"
                          f"{cell(event.new_place)}\t{event.stage}", flush=True)
            else:
                notes.add("skipped", str(event))
                if as_json:  # the line on stderr, as every --json carries it
                    print(json.dumps({"warnings": notes[-1:]}), flush=True)
    if live is None and not as_json and run.idle is not None:
        print(f"# ended: no new frame for {run.idle:g} s; {decided} frames decided ({run.resumed} resumed before), "
              f"{len(notes)} left out; results in {run.path}", flush=True)


# ------------------------------------------------------------------------------------------ evaluate

FORMS = "aligned, aligned:index, positions:Q.csv, pairs:P.csv, matrix:M.npy, vprbench:G.npy, utm-names, exif"


def _truth_source(gt: str, gt_ref: str | None, tolerance: int, radius: float | None,
                  prefix: str = "") -> api.TruthSource:
    """`--gt` is a form name without a file (aligned, utm-names, exif) or KIND:PATH (positions:q.csv,
    pairs:p.csv, matrix:m.npy, vprbench:g.npy), or a path whose suffix tells the form. Options of another form are refused (``prefix``:
    the options' name prefix, ``train_`` for the trained method's)."""
    from wiloc import api

    flag = f"--{prefix.replace('_', '-')}gt"
    kind, sep, path = gt.partition(":")
    if not sep:
        if gt not in NAMED_FORMS and not Path(gt).is_file() and "{query}" not in gt:
            fail(f"{flag}: '{gt}' is neither a ground-truth form nor a file (forms: {FORMS})", EXIT_USAGE)
        kind, path = (gt, "") if gt in NAMED_FORMS else (_guess_kind(gt), gt)
    if kind not in ("aligned", "positions", "pairs", "matrix", "vprbench", "utm-names", "exif"):
        fail(f"{flag}: unknown ground-truth form '{kind}' in '{gt}' (forms: {FORMS})", EXIT_USAGE)
    refuse_unused({f"{prefix}tolerance": (kind == "aligned", "--gt aligned (pairs files carry their own)"),
                   f"{prefix}gt_map": (kind == "positions", "positions ground truth"),
                   f"{prefix}radius": (kind in ("positions", "utm-names", "exif"), "positions, utm-names and exif ground truth")})
    by = "name"
    if kind == "aligned" and path in ("name", "index"):  # aligned:index, by position
        by, path = path, ""
    if kind in NAMED_FORMS and path:
        fail(f"{flag}: '{kind}' reads the traversals themselves and takes no file ('{gt}')", EXIT_USAGE)
    variable = None
    if kind == "matrix" and ".mat:" in path:
        path, variable = path.rsplit(":", 1)
    return api.TruthSource(kind=kind, path=path or None, ref_path=gt_ref, tolerance=tolerance, radius=radius,
                           variable=variable, by=by)


NAMED_FORMS = ("aligned", "utm-names", "exif")  # forms without a file


def _guess_kind(path: str) -> str:
    if Path(path).name.lower() == "ground_truth_new.npy":
        return "vprbench"
    return "matrix" if Path(path).suffix.lower() in (".npy", ".mat") else "pairs"


GT_HELP = ("Ground truth: 'aligned' (same file name, +-tolerance frames; 'aligned:index': same position, "
           "as for a video against a folder of its frames), 'positions:Q.csv' (with "
           "--gt-map R.csv), 'pairs:P.csv' or 'matrix:M.npy|.csv|.mat' ('matrix:M.mat:NAME' picks one array of a .mat), 'vprbench:ground_truth_new.npy' (VPR-Bench), "
           "'utm-names' (@UTM_east@UTM_north@ file names) or 'exif' (the images' GPS EXIF), these two within --radius "
           "metres (default 25). '{query}' in a path is replaced by the query folder's name.")
GtOption = Annotated[str, typer.Option("--gt", help=GT_HELP)]
GtMapOption = Annotated[Optional[str], typer.Option("--gt-map", help="positions: the reference's positions CSV.")]
ToleranceOption = Annotated[int, typer.Option("--tolerance", "-T", min=0, help="aligned: same place within +-T frames (published evaluations use 2).")]
RadiusOption = Annotated[Optional[float], typer.Option("--radius", help="positions, utm-names, exif: same place within this many metres (utm-names, exif: default 25).")]
CutsOption = Annotated[str, typer.Option("--cuts", help="Confidence cuts for precision and recall at a fixed "
                                                        "cut, comma-separated, each in [0, 1].")]
PrPlotOption = Annotated[Optional[Path], typer.Option(callback=_plot_file, show_default="none: not drawn", help="Draw the precision-recall curves.")]
CalibrationPlotOption = Annotated[Optional[Path], typer.Option(
    "--calibration-plot", callback=_plot_file, show_default="none: not drawn", help="Draw the reliability diagram (share correct against confidence).")]
CUTS_TEXT = ",".join(f"{cut:g}" for cut in DEFAULT_CUTS)
RecallAtOption = Annotated[str, typer.Option(
    "--recall-at", help=f"N of Recall@N (a true match among the N best-ranked map frames; runs that rank the map), "
                        f"comma-separated, each 1 to {RANKED}, such as 1,5,10,20.")]
RECALL_AT_TEXT = ",".join(map(str, RANKED_KS))


def _parse_recall_at(text: str) -> list[int]:
    """`--recall-at 1,5,10,20`: whole numbers from 1 to the ranking's length; anything else is a
    usage error."""
    parts = [part.strip() for part in text.split(",") if part.strip()]
    if not parts or not all(part.isdigit() and 1 <= int(part) <= RANKED for part in parts):
        fail(f"--recall-at: '{text}': give whole numbers from 1 to {RANKED} (results keep the {RANKED} best "
             "candidates), comma-separated, such as 1,5,10,20", EXIT_USAGE)
    return sorted({int(part) for part in parts})


def _parse_cuts(text: str) -> list[float]:
    """`--cuts 0.5,0.9,0.99`: numbers in [0, 1]; anything else is a usage error."""
    try:
        cuts = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        cuts = []
    if not cuts or not all(0.0 <= cut <= 1.0 for cut in cuts):
        fail(f"--cuts: '{text}': give confidences in [0, 1], comma-separated, such as {CUTS_TEXT}", EXIT_USAGE)
    return cuts


@app.command(cls=Command)
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
    matrix_plot: Optional[Path] = typer.Option(
        None, callback=_plot_file, show_default="none: not drawn", help="Draw the difference matrix with the decided matches and the ground truth "
                                        "(with several results files: one FILE-RESULTS figure each)."),
    pairs_plot: Optional[Path] = typer.Option(
        None, callback=_plot_file, show_default="none: not drawn", help="Show the most confident right and wrong matches as image pairs (image "
                                        "folders; with several results files: one FILE-RESULTS figure each)."),
    pairs: int = typer.Option(3, "--pairs", min=1, help="With --pairs-plot: show N right and N wrong matches."),
    wrong_only: bool = typer.Option(False, "--wrong-only", help="With --pairs-plot: show the wrong matches only."),
    csv_out: Optional[Path] = typer.Option(None, "--csv", callback=_output_file, show_default="none: not written", help="Write metrics as CSV, and the curves to FILE-curves.csv beside it."),
    cache: CacheOption = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Precision-recall and calibration of results files against ground truth.

    Example: wiloc evaluate day_left-sad-online.csv --gt aligned --tolerance 2 --pr-plot pr.png --cuts 0.9,0.99
    """
    from wiloc import api

    refuse_unused({"pairs": (pairs_plot is not None, "--pairs-plot"), "wrong_only": (pairs_plot is not None, "--pairs-plot")})
    at = _parse_cuts(cuts)
    ranks = _parse_recall_at(recall_at)
    source = _truth_source(gt, gt_map, tolerance, radius)
    evaluations = [api.evaluate(path, source, at, ranks) for path in results]
    notes = _warn_about_truth(evaluations)
    names = short_names([e.path for e in evaluations])
    heads = [{"run": run, "results": name, "method": e.method, "descriptor": e.results.meta.get("descriptor"),
              "traversal": e.traversal, **e.summary.as_dict()}
             for run, name, e in zip(api.run_names(evaluations), names, evaluations)]
    rows = [{**head, **e.calibration_row()} for head, e in zip(heads, evaluations)]
    written = []
    if pr_plot is not None:
        from wiloc.plots import plot_pr
        written.append(plot_pr(dict(zip(api.run_names(evaluations), (e.curve for e in evaluations))),
                               _replacing(notes, pr_plot),
                               title=f"Precision-recall: {api.run_subject(evaluations, source)}"))
    if calibration_plot is not None:
        from wiloc.plots import plot_reliability
        written.append(plot_reliability(api.reliability_series(evaluations), _replacing(notes, calibration_plot),
                                        new_place=api.new_place_series(evaluations)))
    written += _run_plots(evaluations, matrix_plot, pairs_plot, cache, notes, pairs, wrong_only)
    if csv_out is not None:
        written += _write_metrics_csv(csv_out, rows, evaluations, notes)
    if as_json:
        print_command_json("evaluate", "runs", [
            {**head, "results": str(e.path), "ground_truth": source.describe(), **e.calibration_dict(),
             "truth_warnings": e.truth.warnings,
             "curve": {"precision": e.curve.precision.tolist(), "recall": e.curve.recall.tolist(),
                       "thresholds": e.curve.thresholds.tolist()}} for head, e in zip(heads, evaluations)],
            notes, ground_truth=source.describe(), files=[str(p) for p in written])
        return
    for view in metrics_views(rows, at, source.describe()):
        out.print(view)
    for path in written:
        out.print(f"wrote {path}")


def _run_plots(evaluations: list[api.Evaluation], matrix_plot: Path | None, pairs_plot: Path | None,
               cache: Path | None, notes: Notes, pairs: int = 3, wrong_only: bool = False) -> list[Path]:
    """Each run's difference matrix and example pairs (``pairs`` right and wrong ones, or wrong
    ones only); with several runs each file is named after its results file too
    (``matrix-day_left-sad-online.png``)."""
    if matrix_plot is None and pairs_plot is None:
        return []
    from wiloc.cache import Cache
    from wiloc.plots import plot_matrix, plot_pairs
    from wiloc.run_figures import example_pairs, matrix_picture

    store = Cache(cache)
    written = []
    for e in evaluations:
        def target(path: Path) -> Path:
            return path.with_name(f"{path.stem}-{Path(e.name).stem}{path.suffix}") if len(evaluations) > 1 else path
        descriptor = e.results.meta.get("descriptor", "")
        if matrix_plot is not None:
            picture = matrix_picture(e, store)
            written.append(plot_matrix(picture, _replacing(notes, target(matrix_plot)), title=(
                f"{e.method} on {picture.query} against {picture.reference} ({descriptor}): differences, "
                "decided matches and ground truth")))
        if pairs_plot is not None:
            shown = "wrong matches" if wrong_only else "right and wrong matches"
            written.append(plot_pairs(example_pairs(e, pairs, wrong_only), _replacing(notes, target(pairs_plot)),
                                      title=f"{e.method} on {e.traversal} ({descriptor}): the most confident {shown}"))
    return written


def _warn_about_truth(evaluations: list[api.Evaluation]) -> Notes:
    """Name-matching warnings, and runs whose ground truth leaves nothing to recall."""
    notes = Notes()
    for e in evaluations:
        for warning in e.truth.warnings:
            notes.add("warning", f"{e.path}: {warning}")
        if not e.truth.has_match().any():
            notes.add("warning", f"{e.path}: no frame has a true match under this ground truth, so every "
                                 "recall is 0 (check --gt, --tolerance, --radius)")
    return notes


def _write_metrics_csv(path: Path, rows: list[dict[str, Any]], evaluations: list[api.Evaluation],
                       notes: Notes) -> list[Path]:
    """The metrics to ``path`` and the curves to ``<stem>-curves.csv`` beside it; a file replaced
    is said so. Returns both paths."""
    import pandas as pd

    curves_path = path.with_name(path.stem + "-curves.csv")
    curves = pd.concat([pd.DataFrame({"results": str(e.path), "threshold": e.curve.thresholds,
                                      "precision": e.curve.precision, "recall": e.curve.recall})
                        for e in evaluations])
    for target, frame in ((path, pd.DataFrame(rows)), (curves_path, curves)):
        with written_whole(_replacing(notes, target), "the metrics file") as file:
            frame.to_csv(file, index=False)
    return [path, curves_path]


def _replacing(notes: Notes, path: Path) -> Path:
    """``path``, about to be written: an existing file there is said to be replaced, as
    results files are."""
    if path.exists():
        notes.add("note", f"replaced the existing file {path}")
    return path


# ------------------------------------------------------------------------------------------- compare

@app.command(cls=Command)
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
    threshold_plot: Optional[Path] = typer.Option(None, callback=_plot_file, show_default="none: not drawn", help="Precision against normalised threshold (the paper's Figure 5)."),
    model_plot: Optional[Path] = typer.Option(None, callback=_plot_file, show_default="none: not drawn", help="Learned histograms of the first online run (Figure 1)."),
    pr_plot: PrPlotOption = None,
    calibration_plot: CalibrationPlotOption = None,
    csv_out: Optional[Path] = typer.Option(None, "--csv", callback=_output_file, show_default="none: not written",
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
    shown = [flag for flag, given in (("--markdown", markdown), ("--latex", latex), ("--json", as_json)) if given]
    if len(shown) > 1:
        fail(f"{shown[1]}: give one of --markdown, --latex and --json", EXIT_USAGE)
    try:
        targets = [float(p) for p in precision.split(",") if p.strip()]
    except ValueError:
        fail(f"--precision: '{precision}': give percentages such as 100,99.5", EXIT_USAGE)
    at = _parse_cuts(cuts)
    ranks = _parse_recall_at(recall_at)
    source = _truth_source(gt, gt_map, tolerance, radius)
    comparison = api.compare(results, source, precisions=targets, global_thresholds=global_threshold, cuts=at,
                             recall_at=ranks)
    notes = _warn_about_truth(comparison.evaluations)
    written = _compare_plots(comparison, source, threshold_plot, model_plot, pr_plot, calibration_plot, notes)
    records = comparison_records(comparison)
    if csv_out is not None:
        (_, table1, _, _), (_, calibration, _, _) = records[:2]
        runs = [{"results": str(e.path), "descriptor": e.results.meta.get("descriptor"), **a, **b}
                for e, a, b in zip(comparison.evaluations, table1, calibration)]
        written += _write_metrics_csv(csv_out, runs, comparison.evaluations, notes)
    if markdown or latex:
        from wiloc.text_tables import latex as as_latex
        from wiloc.text_tables import markdown as as_markdown
        for title, rows, columns, labels in records[:None if global_threshold else 2]:
            print(as_latex(rows, columns, labels, title) if latex else f"**{title}**\n\n{as_markdown(rows, columns, labels)}",
                  end="\n\n")
        for path in written:
            note("wrote", str(path))  # stdout holds the tables alone
        return
    if as_json:
        print_command_json("compare", "runs", run_records(comparison), notes, ground_truth=comparison.ground_truth,
                           table2=comparison.table2.to_dict(orient="records"), files=[str(p) for p in written])
        return
    out.print(table1_view(comparison))
    for view in cut_views(comparison, at):
        out.print(view)
    if (view := new_place_view(comparison.cut_table.to_dict(orient="records"), at, comparison.ground_truth,
                               ["method", "traversal"])) is not None:
        out.print(view)
    if global_threshold:
        out.print(table2_view(comparison))
    for path in written:
        out.print(f"wrote {path}")


def _compare_plots(comparison: api.Comparison, source: api.TruthSource, threshold_plot: Path | None,
                   model_plot: Path | None, pr_plot: Path | None, calibration_plot: Path | None,
                   notes: Notes) -> list[Path]:
    from wiloc import api, plots

    subject = api.run_subject(comparison.evaluations, source)
    written = []
    if threshold_plot is not None:
        written.append(plots.plot_threshold(api.threshold_series(comparison), _replacing(notes, threshold_plot),
                                            marks=api.threshold_marks(comparison),
                                            title=f"Precision against threshold: {subject}"))
    if model_plot is not None:
        learned = sorted((e for e in comparison.evaluations if e.method in ("online", "trained")),
                         key=lambda e: e.method != "online")
        if not learned:
            fail(f"{model_plot}: none of the results is an online or trained run with a model", EXIT_BAD_INPUT)
        written.append(plots.plot_model(learned[0].results.model, _replacing(notes, model_plot),
                                        title=f"Learned model: {learned[0].method}, {learned[0].traversal}"))
    if pr_plot is not None:
        written.append(plots.plot_pr(api.pr_series(comparison), _replacing(notes, pr_plot),
                                     title=f"Precision-recall: {subject}"))
    if calibration_plot is not None:
        written.append(plots.plot_reliability(api.reliability_series(comparison.evaluations),
                                              _replacing(notes, calibration_plot),
                                              new_place=api.new_place_series(comparison.evaluations)))
    return written


# -------------------------------------------------------------------------------------------- report

def _html_file(value: Path) -> Path:
    """The report's file: its folder must exist, its name end in .html."""
    _output_file(value)
    if value.suffix.lower() not in (".html", ".htm"):
        raise typer.BadParameter(f"'{value}': the report is an HTML page; end the name in .html")
    return value


@app.command(cls=Command)
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
    thumb_width: int = typer.Option(160, min=40, max=640, help="Width in pixels of the frame browser's images."),
    cache: CacheOption = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a line."),
) -> None:
    """One self-contained HTML page of a comparison: tables, figures, per run a timeline and the
    difference matrix, and a frame browser. It needs no network; images are embedded as thumbnails.

    Example: wiloc report runs/day_left-sad-online.csv runs/day_left-sad-catgraph.csv --gt aligned -o report.html
    """
    from wiloc import api
    from wiloc.cache import Cache
    from wiloc.report import write_report

    at = _parse_cuts(cuts)
    source = _truth_source(gt, gt_map, tolerance, radius)
    comparison = api.compare(results, source, cuts=at)
    notes = _warn_about_truth(comparison.evaluations)
    with progress_bar(not as_json) as progress:
        written = write_report(comparison, _replacing(notes, out_file), cache=Cache(cache), thumb_width=thumb_width,
                               title=f"wiloc report: {api.run_subject(comparison.evaluations, source)}",
                               progress=progress)
    for note in written.notes:
        notes.add("note", note)
    if as_json:
        print_command_json("report", "results", [{"file": str(written.path), "size": written.size,
                                                  "images": written.images, "thumb_width": written.thumb_width}],
                           notes)
        return
    out.print(f"wrote {written.path} ({written.size / 1e6:.1f} MB, {written.images} images "
              f"at most {written.thumb_width} px wide)")


# ---------------------------------------------------------------------------------------------- demo

@app.command(cls=Command)
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
