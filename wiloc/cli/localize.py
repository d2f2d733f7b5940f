"""`wiloc localize`: parse the run's inputs and options, localize each query (or follow a folder
as it fills) through wiloc.api, and render one row per run."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from wiloc.candidates import DEFAULT_EXCLUDE_RECENT
from wiloc.cli.core import Notes, fail, handles_errors, refuse_unused
from wiloc.cli.localize_views import show_followed, show_runs
from wiloc.cli.options import (DESCRIBED, STREAMS, CacheOption, DescriptorOption, EveryOption, FpsOption,
                               JobsOption, ModelOption, PreprocessOption, SchedulerOption, StartOption, StopOption,
                               TopicOption, VocabularyOption, descriptor_params_given, metric_name, names_folder,
                               plot_file, results_out, sampling_given)
from wiloc.cli.params import descriptor_uses, given, method_params, with_descriptor_options, with_method_options
from wiloc.cli.truth import truth_source
from wiloc.cli.views import progress_bar
from wiloc.errors import EXIT_USAGE
from wiloc.methods.registry import METHODS, learning_from_the_map, method_class


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
    metric: Optional[str] = typer.Option(None, callback=metric_name, show_default="the file's recorded metric", help="For descriptor matrix files: l1 | sqeuclidean | hamming | cosine"),
    method: str = typer.Option("online", help=" | ".join(METHODS)),
    exclude_recent: int = typer.Option(DEFAULT_EXCLUDE_RECENT, "--exclude-recent", "-R", help="Recent frames excluded as candidates (sequence mode) and around each map frame when learning from the map."),
    train_query: Optional[Path] = typer.Option(None, help="trained: labelled training query traversal.", rich_help_panel="trained inputs"),
    train_map: Optional[Path] = typer.Option(None, help="trained: its reference traversal.", rich_help_panel="trained inputs"),
    train_gt: Optional[str] = typer.Option(None, help="trained: ground truth, as --gt of `wiloc evaluate`.", rich_help_panel="trained inputs"),
    train_gt_map: Optional[str] = typer.Option(None, help="trained: the training map's positions CSV (positions form).", rich_help_panel="trained inputs"),
    train_tolerance: int = typer.Option(2, min=0, help="trained: +-frames for aligned ground truth.", rich_help_panel="trained inputs"),
    train_radius: Optional[float] = typer.Option(None, help="trained: metres, for positions ground truth.", rich_help_panel="trained inputs"),
    names: Optional[Path] = typer.Option(None, help="A .npy QUERY matrix: its frame names, one per line."),
    map_names: Optional[Path] = typer.Option(None, help="A .npy --map matrix: its frame names, one per line."),
    odometry: Optional[Path] = typer.Option(None, help="catgraph: the odometry CSV of one QUERY (name,distance or name,x,y), with the map's (--map-odometry); without --map, the traversal's own.", rich_help_panel="catgraph inputs"),
    odometry_topic: Optional[str] = typer.Option(None, help="catgraph: the nav_msgs Odometry topic of the ROS bags (the query's and the --map bag's; without --map, the traversal's own).", rich_help_panel="catgraph inputs"),
    map_odometry: Optional[Path] = typer.Option(None, help="catgraph: reference odometry CSV.", rich_help_panel="catgraph inputs"),
    out_text: Optional[str] = typer.Option(None, "--out", "-o", callback=results_out, show_default="QUERY-DESCRIPTOR-METHOD.csv here",
                                            help="Results file (a folder with several queries)."),
    model_plot: Optional[Path] = typer.Option(None, callback=plot_file, show_default="none: not drawn", help="online/trained: draw the learned histograms of one QUERY's run (the paper's Figure 1)."),
    cache: CacheOption = None,
    jobs: JobsOption = None,
    scheduler: SchedulerOption = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables (with --follow: one JSON line per frame)."),
    every: EveryOption = 1,
    fps: FpsOption = None,
    start: StartOption = "0",
    stop: StopOption = None,
    topic: TopicOption = None,
    map_topic: Optional[str] = typer.Option(None, show_default="--topic", rich_help_panel=STREAMS,
                                            help="ROS bags: the --map bag's image topic, when it is not --topic's "
                                                 "(a map recorded by another camera or driver)."),
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
    from wiloc.cache.store import Cache
    from wiloc.description.traversals import check_query_path, names_matrix_file

    method_class(method)
    params = method_params(method, method_options or {})
    matrices = [names_matrix_file(Path(p)) for p in (*queries, reference, train_query, train_map) if p is not None]
    refuse_unused({"descriptor": (not all(matrices), DESCRIBED),
                   **descriptor_uses(descriptor, described=not all(matrices)),
                   "metric": (any(matrices), "descriptor matrix files (.npy, .npz, .csv, .h5)"),
                   "jobs": ((not all(matrices) and scheduler is None) or scheduler == "local",
                            f"{DESCRIBED} described on this machine, and a local Dask cluster (--scheduler local)"),
                   "names": (any(names_matrix_file(q) for q in queries), "a descriptor matrix file as QUERY"),
                   "map_names": (reference is not None and names_matrix_file(reference),
                                 "a descriptor matrix file as --map"),
                   "map_odometry": (reference is not None, "map mode (--map)"),
                   "map_topic": (reference is not None, "map mode (--map)"),
                   "exclude_recent": (reference is None or "map_self" in method_class(method).needs,
                                      "sequence mode, and in map mode to the methods that learn from the map's "
                                      f"differences to itself ({', '.join(learning_from_the_map())})"),
                   "idle": (follow, "--follow")})
    train_inputs = (train_query, train_map, train_gt)
    trained = [name for name, kind in METHODS.items() if "training" in kind.needs]  # before "go together"
    refuse_unused({name: (method in trained, f"the methods trained on a labelled pair ({', '.join(trained)})")
                   for name in ("train_query", "train_map", "train_gt")})
    refuse_unused({name: (any(train_inputs), "a training pair (--train-query, --train-map, --train-gt)")
                   for name in ("train_gt_map", "train_tolerance", "train_radius")})
    training = None
    if any(train_inputs):
        for option, value in zip(("--train-query", "--train-map", "--train-gt"), train_inputs):
            if value is None:
                fail(f"{option}: missing; --train-query, --train-map and --train-gt go together", EXIT_USAGE)
        training = api.Training(train_query, train_map,
                                truth_source(train_gt, train_gt_map, train_tolerance, train_radius, prefix="train_"))
    sampling = sampling_given(every, fps, start, stop)
    out_path = None if out_text is None else Path(out_text)
    out_folder = out_text is not None and names_folder(out_text)
    recent = exclude_recent if given("exclude_recent") else None  # the library refuses it where it does nothing
    if follow:
        refused = [flag for flag, value in (("--odometry", odometry), ("--odometry-topic", odometry_topic),
                                            ("--topic", topic), ("--map-topic", map_topic), ("--names", names),
                                            ("--map-names", map_names), ("--metric", metric),
                                            ("--model-plot", model_plot), ("--map-odometry", map_odometry))
                   if value is not None]
        refused += ["video sampling"] * (sampling != api.Sampling())
        if len(queries) != 1 or refused:
            fail(f"--follow: takes one query folder{' and not ' + ', '.join(refused) if refused else ''}", EXIT_USAGE)
        show_followed(queries[0], api.follow_folder(
            queries[0], reference=reference, descriptor=descriptor,
            descriptor_params=descriptor_params_given(descriptor, descriptor_options, vocabulary, cache, model, preprocess),
            method=method, method_params=params,
            exclude_recent=recent, training=training,
            out=out_path / api.results_name(queries[0], method, descriptor) if out_folder else out_path,
            cache=Cache(cache), jobs=jobs, idle=idle), as_json)
        return
    if len(queries) > 1 and odometry is not None:  # one log is one traversal's: never another query's
        fail("--odometry: the log of one query; give one QUERY with it", EXIT_USAGE)
    if len(queries) > 1 and out_path is not None and not out_folder:
        fail(f"{out_path}: with several queries --out names a folder", EXIT_USAGE)
    if model_plot is not None and method not in ("online", "trained"):
        fail(f"--model-plot: method '{method}' learns no histogram model to draw", EXIT_USAGE)
    if model_plot is not None and len(queries) > 1:
        fail("--model-plot: draws one run's histograms; give one QUERY", EXIT_USAGE)
    if out_path is not None and not out_folder:
        targets = [out_path]
    else:
        targets = [(out_path or Path.cwd()) / api.results_name(q, method, descriptor, metric) for q in queries]
    clash = next((t for t in targets if targets.count(t) > 1), None)
    if clash is not None:
        fail(f"{clash}: two queries would write the same results file; give each its own --out", EXIT_USAGE)
    if len(queries) > 1:  # each before the first is localized (a bad second one failed after its results were
        for query in queries:  # written); one alone is checked by its run, after the options the library checks
            check_query_path(query)
    cautions = Notes()
    for line in _doubtful(queries, reference, training):
        cautions.add("warning", line)
    store = Cache(cache)
    runs, repairs = [], []
    with progress_bar(not as_json) as progress:
        for query, target in zip(queries, targets):
            known = len(store.repairs)
            runs.append(api.localize(query, reference=reference, descriptor=descriptor if given("descriptor") else None,
                                     sampling=sampling,
                                     descriptor_params=descriptor_params_given(descriptor, descriptor_options, vocabulary,
                                                                              cache, model, preprocess),
                                     metric=metric, method=method, method_params=params,
                                     exclude_recent=recent, training=training,
                                     odometry=odometry, map_odometry=map_odometry,
                                     query_names_file=names, ref_names_file=map_names, out=target,
                                     cache=store, jobs=jobs, progress=progress, scheduler=scheduler,
                                     topic=topic, map_topic=map_topic, odometry_topic=odometry_topic))
            repairs.append(store.repairs[known:])
    show_runs(runs, repairs, method, model_plot, as_json, cautions)


def _same(a: Path | None, b: Path | None) -> bool:
    """Whether ``a`` and ``b`` are one traversal; a path that cannot be resolved (a symbolic link
    loop) is compared as written, and reading it says what is wrong."""
    return a is not None and b is not None and _resolved(a) == _resolved(b)


def _resolved(path: Path) -> Path:
    try:
        return path.resolve()
    except (OSError, RuntimeError):  # RuntimeError: a loop, before Python 3.13
        return path.absolute()


def _doubtful(queries: list[Path], reference: Path | None, training: Any) -> list[str]:
    """What makes a run measure better than it would on new data: a query that is the map itself
    (each frame's best match is itself), a trained model tested on its own training pair."""
    lines = [f"{q}: the query is the map itself, so each frame matches itself; for loop closure within one "
             "traversal leave out --map (sequence mode)" for q in queries if _same(q, reference)]
    if training is not None and _same(reference, training.reference):
        lines += [f"{q}: --method trained is tested on its own training pair (--train-query, --train-map); its "
                  "confidences will look better than on another pair" for q in queries if _same(q, training.query)]
    return lines
