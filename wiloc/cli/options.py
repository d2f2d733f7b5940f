"""Options several commands share: their types and help, the checks of output files made as the
options are read (before any work), and the descriptor parameters the flags set."""
from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer
from typer._click.core import ParameterSource

from wiloc.atomic import NOT_A_FILE, name_problem, output_problem
from wiloc.cli.core import EMPTY_PATH, Notes, fail, note
from wiloc.cli.params import descriptor_params, descriptor_takers
from wiloc.errors import EXIT_USAGE, UsageError, WilocError

if TYPE_CHECKING:
    from wiloc.sources.video import Sampling


def output_file(value: Path | None) -> Path | None:
    """An output file option (``--csv``, ``--out FILE.csv``, a plot), checked as the options are
    read, before any work: its folder must exist (a typo is not made into new folders; folders
    that ``--out`` names are created), and something there must be a regular file (a device or a
    pipe would be replaced, not written to), and not the file the command prints to. ``-`` is
    refused: it is no name for standard output here (``--json`` prints for scripts)."""
    if value is None:
        return None
    if str(value) == "-":
        raise typer.BadParameter("-: wiloc writes files here, not standard output (give a file name)")
    if (problem := name_problem(value)) is not None:
        raise typer.BadParameter(f"{value}: {problem}")
    if value.suffix and not value.is_dir() and not value.parent.is_dir():
        if value.parent.exists():
            raise typer.BadParameter(f"{value.parent} is not a folder (the file would go into it)")
        raise typer.BadParameter(f"the folder {value.parent} does not exist (create it first)")
    problem = None if value.is_dir() else output_problem(value)
    if problem is not None:
        raise typer.BadParameter(f"{value}: {problem}")
    return value


def results_out(value: str | None) -> str | None:
    """localize's ``--out``, checked as :func:`output_file` checks a file, before any work, and a
    file where it names a folder (:func:`names_folder`) refused; kept as typed, since a trailing
    ``/`` names a folder even where the name has a suffix (``runs.v2/``), which a path would lose."""
    if value is None:
        return None
    if not value:  # Path('') is the current folder
        raise typer.BadParameter(EMPTY_PATH)
    path = Path(value)
    trailing = _trailing_separator(value)
    if not trailing:
        output_file(path)
    elif (problem := name_problem(path)) is not None:
        raise typer.BadParameter(f"{path}: {problem}")
    if names_folder(value) and path.exists() and not path.is_dir():
        why = "" if trailing else " (a name without a suffix names a folder)"
        raise typer.BadParameter(f"{path} is a file, not a folder{why}")
    return value


def names_folder(value: str) -> bool:
    """Whether localize's ``--out`` names a folder: one that exists, a name without a suffix, or
    one ending in ``/``."""
    path = Path(value)
    return _trailing_separator(value) or path.is_dir() or not path.suffix


def _trailing_separator(value: str) -> bool:
    return value.endswith(("/", os.sep))


def cache_folder(ctx: typer.Context, value: Path | None) -> Path | None:
    """A ``--cache`` option (or ``WILOC_CACHE``, named as such when the folder came from it),
    checked as the options are read: no file may be where the folder, or a folder it would be made
    in, is. A folder that does not exist is made when something is described into it."""
    if value is None:
        return None
    existing = next((path for path in (value, *value.absolute().parents) if path.exists()), None)
    if existing is not None and not existing.is_dir():
        problem = (f"{existing} is a file, not a cache folder"
                   + (f" (the cache would be made in it: {value})" if existing != value else ""))
        if ctx.get_parameter_source("cache") == ParameterSource.ENVIRONMENT:
            raise typer.BadParameter(problem, param_hint="WILOC_CACHE")
        raise typer.BadParameter(problem)
    return value


def metric_name(value: str | None) -> str | None:
    """A ``--metric`` option, checked as the options are read: one of the metrics descriptors are
    compared with (a typo was found only once the matrix file was read, as bad input)."""
    from wiloc.descriptors.base import METRICS

    if value is not None and value not in METRICS:
        raise typer.BadParameter(f"'{value}' is no metric; give one of {', '.join(METRICS)}")
    return value


def descriptor_name(value: str) -> str:
    """A ``--descriptor`` option, checked as the options are read: ``external`` names imported
    matrices (their metric and length read from the file), so it describes no image (it failed
    on a metric the command line cannot give)."""
    from wiloc.cache.entries import EXTERNAL

    if value == EXTERNAL:
        raise typer.BadParameter(f"'{EXTERNAL}' names imported descriptor matrices, which are not described: give "
                                 "the matrix file itself (as QUERY or --map, or to describe --import), or describe "
                                 "images with another descriptor (describe --list-descriptors)")
    return value


def one_file(value: Path | None) -> Path | None:
    """An output option that names one file (a table, a figure, a page): checked as
    :func:`output_file`, and a folder there is refused too, before any work, since writing the
    file would replace it."""
    if output_file(value) is not None and value.is_dir():
        raise typer.BadParameter(f"{value}: {NOT_A_FILE}")
    return value


def plot_file(value: Path | None) -> Path | None:
    """A plot option's file, checked as the options are read, before any work: its folder must
    exist, nothing but a file be there, its suffix name a format the figures can be written in."""
    if one_file(value) is not None:
        from wiloc.figures.plots import check_plot_path
        try:
            check_plot_path(value)
        except WilocError as exc:
            raise typer.BadParameter(exc.problem) from None
    return value


def separate_outputs(read: list[Path], written: dict[str, Path | list[Path] | None]) -> None:
    """A usage error, before any work, for an output option (``written``: option -> its file, or
    the files it writes, None when not given) whose file another output option names too, or is
    one of the files the command reads: the later write would replace it (a figure by a table, a
    run by its metrics or their curves); or one that no file can take (:func:`output_problem`: a
    folder there, a name too long), which a file named from the option's, as a run's figure with
    several runs, meets only here."""
    taken = {path.resolve(): "one of the results files read" for path in read}
    for option, paths in written.items():
        for path in [paths] if isinstance(paths, Path) else paths or []:
            if (problem := output_problem(path)) is not None:
                raise UsageError(option, f"{path}: {problem}")
            if (owner := taken.get(path.resolve())) is not None:
                raise UsageError(option, f"{path} is {owner}; give each output a file of its own")
            taken[path.resolve()] = f"{option}'s file"


def replacing(notes: Notes, path: Path) -> Path:
    """``path``, about to be written: an existing file there is said to be replaced, as
    results files are."""
    if path.exists():
        notes.add("note", f"replaced the existing file {path}")
    return path


def descriptor_params_given(descriptor: str, options: dict[str, Any] | None, vocabulary: str | None,
                            cache: Path | None, model: Path | None = None,
                            preprocess: list[str] | None = None) -> dict[str, Any]:
    """The descriptor parameters the command line sets: its options typed (and those always
    passed), a vocabulary ``file`` from --vocabulary (needed by a descriptor taking one), a
    ``model`` from --model (likewise) with --preprocess KEY=VALUE. A descriptor that is not built
    in comes from a plugin: plugins that failed to load are warned of."""
    from wiloc.descriptors.registry import BUILT_IN, DESCRIPTORS, plugin_problems

    if descriptor not in DESCRIPTORS or DESCRIPTORS[descriptor].source != BUILT_IN:
        for problem in plugin_problems():
            note("warning", problem)
    params = descriptor_params(options or {})
    if descriptor in descriptor_takers("file"):
        if vocabulary is None:
            fail(f"--vocabulary: --descriptor {descriptor} needs one (a file, or a key from `wiloc vocabulary`)",
                 EXIT_USAGE)
        from wiloc import api
        from wiloc.cache.store import Cache
        params["file"] = str(api.vocabulary_file(vocabulary, Cache(cache)))
    if descriptor in descriptor_takers("model"):
        if model is None:
            fail(f"--model: --descriptor {descriptor} needs one (an .onnx model file)", EXIT_USAGE)
        preprocess_given = _preprocess_options(preprocess or [])
        _check_preprocess(model, preprocess_given)
        params.update({"model": str(model), **preprocess_given})
    return params


def _check_preprocess(model: Path, given: dict[str, str]) -> None:
    """--preprocess values checked against the model before any work, so that one that cannot work
    is a usage error naming --preprocess (the library names its parameter, the descriptor). A model
    that fails without them (its own metadata, less what they replace) is left to the library's
    error."""
    from dataclasses import replace

    from wiloc.descriptors.learned import open_network, preprocessing

    if not given:
        return
    network = open_network(model)
    rest = replace(network, metadata={k: v for k, v in network.metadata.items() if k not in given})
    try:  # a given input_size is what a model of any input size needs: stand in for it
        preprocessing(rest, {"input_size": list(network.input_size or (1, 1))} if "input_size" in given else {})
    except ValueError:
        return
    try:
        preprocessing(network, given)
    except ValueError as exc:
        raise UsageError("--preprocess", str(exc)) from None


def _preprocess_options(items: list[str]) -> dict[str, str]:
    """`--preprocess KEY=VALUE` options as {key: value text}, keys those of the model metadata,
    each given once (a repeated key kept its last value without a word)."""
    from wiloc.descriptors.learned import KEYS

    given: dict[str, str] = {}  # key: the option giving it
    for item in items:
        key = item.partition("=")[0].strip()
        if "=" not in item or key not in KEYS:
            fail(f"--preprocess: '{item}': give KEY=VALUE, KEY one of {', '.join(KEYS)}", EXIT_USAGE)
        if key in given:
            fail(f"--preprocess: {key} given twice ('{given[key]}', '{item}'); give each key once", EXIT_USAGE)
        given[key] = item
    return {key: item.partition("=")[2].strip() for key, item in given.items()}


DescriptorOption = Annotated[str, typer.Option(
    "--descriptor", "-d", callback=descriptor_name, help="sad | gist | brisk-gist | bow (with --vocabulary; fabmap and catgraph then read "
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
                                                     callback=cache_folder, help="Cache folder.")]
JobsOption = Annotated[Optional[int], typer.Option("--jobs", "-j", show_default="all cores",
                                                   help="Worker processes for describing image folders (onnx: threads).")]
TrainingJobsOption = Annotated[Optional[int], typer.Option(
    "--jobs", "-j", show_default="all cores",
    help="Worker processes that extract the training images' local features.")]
STREAMS = "video files and ROS bags"
#: What wiloc describes (a descriptor applies to), besides descriptor matrices imported.
DESCRIBED = f"image folders, {STREAMS}"
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


def sampling_given(every: int, fps: float | None, start: str, stop: str | None) -> Sampling:
    """The video sampling the options say; --fps with --every is refused in the flags the user
    typed (the library's message names its parameters, ``every``)."""
    from wiloc.sources.video import Sampling

    if fps is not None and every != 1:
        raise UsageError("--fps", f"does not go with --every (got --every {every}); give one of them")
    return Sampling(every=every, fps=fps, start=start, stop=stop)


PrPlotOption = Annotated[Optional[Path], typer.Option(callback=plot_file, show_default="none: not drawn", help="Draw the precision-recall curves.")]
CalibrationPlotOption = Annotated[Optional[Path], typer.Option(
    "--calibration-plot", callback=plot_file, show_default="none: not drawn", help="Draw the reliability diagram (share correct against confidence).")]
