"""`wiloc describe`: whole-image descriptors of image folders, videos and ROS bags into the cache,
descriptors imported from other tools, and what the cache and the descriptor registry hold."""
from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any, Optional

import typer

from wiloc.cli.core import Notes, error, fail, handles_errors, out, refuse_besides, refuse_unused
from wiloc.cli.options import (DESCRIBED, SAMPLING, STREAMS, CacheOption, DescriptorOption, EveryOption, FpsOption,
                               JobsOption, ModelOption, PreprocessOption, SchedulerOption, StartOption, StopOption,
                               TopicOption, VocabularyOption, descriptor_params_given, metric_name, output_file,
                               sampling_given)
from wiloc.cli.params import descriptor_uses, with_descriptor_options
from wiloc.cli.views import print_command_json, progress_bar, table
from wiloc.errors import EXIT_BAD_INPUT, EXIT_USAGE
from wiloc.labels import short_names

#: What describe takes, said when it is given another file.
TAKES = "describe takes folders of images, video files and ROS bags, and descriptor matrices with --import"


@handles_errors
@with_descriptor_options
def describe(
    folders: list[Path] = typer.Argument(None, metavar="FOLDER...", show_default=False,
                                         help="Image folders, video files or ROS bags (one traversal each)."),
    descriptor: DescriptorOption = "sad",
    vocabulary: VocabularyOption = None,
    model: ModelOption = None,
    preprocess: PreprocessOption = None,
    import_file: Optional[Path] = typer.Option(None, "--import", help="External descriptors: an N x D matrix (.npy, .npz, .csv, .h5), hloc's global-feats-*.h5, or a folder of per-image .npy files (with --out)."),
    names: Optional[Path] = typer.Option(None, help="With --import .npy: text file of frame names, one a line."),
    metric: Optional[str] = typer.Option(None, callback=metric_name, show_default="the file's recorded metric, else l1", help="With --import: l1 | sqeuclidean | hamming | cosine"),
    import_out: Optional[Path] = typer.Option(None, "--out", "-o", callback=output_file, show_default="none: only the cache",
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
    from wiloc.cache.store import Cache
    from wiloc.description.describing import is_stream
    from wiloc.sources.frames import not_a_traversal

    importing = import_file is not None
    if list_cache and (folders or importing):
        fail("--list: shows what the cache holds; give it no FOLDER and no --import", EXIT_USAGE)
    if list_descriptors:
        if folders or importing or list_cache:
            fail("--list-descriptors: shows the descriptors there are; give it no FOLDER, --import or --list",
                 EXIT_USAGE)
        refuse_besides("list_descriptors", ("as_json",))
        _list_descriptors(as_json)
        return
    if list_cache:
        refuse_besides("list_cache", ("cache", "as_json"))
    refuse_unused({"descriptor": (not importing, DESCRIBED),
                   **descriptor_uses(descriptor, described=not importing),
                   "metric": (importing, "--import"), "names": (importing, "--import"),
                   "import_out": (importing, "--import"), "prefix": (import_out is not None, "--import with --out"),
                   "jobs": (not importing and scheduler in (None, "local"),
                            "image folders described on this machine or a local Dask cluster (--scheduler local)"),
                   **{name: (not importing, STREAMS) for name in (*SAMPLING, "topic")}})
    store = Cache(cache)
    if list_cache:
        _list_cache(store, as_json)
        return
    if not importing and not folders:
        fail("FOLDER...: give image folders, video files, ROS bags, --import FILE or --list", EXIT_USAGE)
    sampling = sampling_given(every, fps, start, stop)
    for path in folders or ():
        if path.is_file() and not is_stream(path):
            fail(f"{path}: {not_a_traversal(path, TAKES)}", EXIT_BAD_INPUT)
    with progress_bar(not as_json) as progress:
        if importing:
            reports = [api.import_descriptors(import_file, metric=metric, names=names, cache=store, out=import_out,
                                              prefix=prefix)]
        else:  # one call: the folders' frames form one stream over the workers
            reports = api.describe(folders, descriptor,
                                   descriptor_params=descriptor_params_given(descriptor, descriptor_options, vocabulary, cache,
                                                                        model, preprocess),
                                   cache=store, jobs=jobs, progress=progress, sampling=sampling, scheduler=scheduler,
                                   topic=topic)
    rows, notes = [], []
    given = folders if not importing and len(folders) == len(reports) else [Path(r.folder) for r in reports]
    for label, r, folder in zip(short_names([r.folder for r in reports]), reports, given):
        said = Notes()
        for line in (*r.repairs, *r.notes):
            said.add("note", line)
        for name, reason in r.left_out if not r.video else ():  # named as localize names them: absolute in --json
            said.add("skipped", f"{Path(r.folder if as_json else folder) / name}: {reason}")
        if len(r.sizes) > 1:
            shown = ", ".join(f"{w} x {h}" for w, h in r.sizes[:4]) + (", ..." if len(r.sizes) > 4 else "")
            said.add("note", f"{r.folder}: images of {len(r.sizes)} different sizes ({shown})")
        notes.append(said)
        rows.append({"folder": label, "descriptor": r.descriptor, "frames": r.frames,
                     "shape": list(r.shape), "computed": r.computed, "reused": r.reused,
                     "failed": len(r.failed), "images_per_second": r.images_per_second if r.computed else None})
    if as_json:
        print_command_json("describe", "results", [{**row, "folder": r.folder, "failed_frames": [list(f) for f in r.failed],
                                                    "unusable": [list(u) for u in r.unusable],
                                                    "ignored": list(r.ignored)} for row, r in zip(rows, reports)],
                           [line for said in notes for line in said])
    else:
        out.print(table("describe", [{**row, "shape": "x".join(map(str, row["shape"]))} for row in rows],
                        labels={"images_per_second": "rows/s" if importing else "images/s"},  # an import reads rows
                        digits={"images_per_second": 1}))
    # A video that stops decoding early is an error, after its good frames went into the cache.
    problems = [f"{r.folder}: {reason}" for r in reports if r.video for _, reason in r.failed]
    problems += [f"{r.folder}: no image could be described (see the lines above)"  # unless a video's line said why
                 for r in reports if r.entry.data.shape[0] == 0 and not (r.video and r.failed)]
    for problem in problems:
        error(problem)
    if problems:
        raise typer.Exit(EXIT_BAD_INPUT)


def _list_cache(store: Any, as_json: bool) -> None:
    """`describe --list`: one row per cache entry, told apart by folder, descriptor and parameters,
    and one per setting of the local features kept for vocabularies and ``bow`` (descriptor
    "local features", frames: the images kept); a cache folder that does not exist (a misspelt
    --cache) is said to, not shown as an empty one."""
    from wiloc.cache.features import list_features

    notes = Notes()
    if not store.root.exists():
        notes.add("note", f"{store.root}: no such cache folder; nothing has been described into it")
    infos = [*store.list_entries(), *list_features(store)]
    if as_json:
        print_command_json("describe", "results", [asdict(info) for info in infos], notes)
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
    defaults (the version of the descriptor's code when not the present one's), a video's or bag's
    sampling and topic, an import's metric; never the content digests."""
    from wiloc.descriptors.registry import DESCRIPTOR_NAMES, get_descriptor

    defaults = get_descriptor(descriptor).cache_params if descriptor in DESCRIPTOR_NAMES else {}
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
