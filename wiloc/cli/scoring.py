"""What evaluate, compare and report share: confidence cuts and Recall@N as options, warnings
about ground truth that leaves nothing to recall, and the metrics CSV."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer

from wiloc.atomic import output_problem, written_whole
from wiloc.candidates import RANKED
from wiloc.cli.core import Notes, fail
from wiloc.cli.options import one_file, replacing
from wiloc.errors import EXIT_USAGE
from wiloc.evaluation.metrics import RANKED_KS
from wiloc.evaluation.reliability import DEFAULT_CUTS

if TYPE_CHECKING:
    from wiloc import api

CutsOption = Annotated[str, typer.Option("--cuts", help="Confidence cuts for precision and recall at a fixed "
                                                        "cut, comma-separated, each in [0, 1].")]
CUTS_TEXT = ",".join(f"{cut:g}" for cut in DEFAULT_CUTS)
RecallAtOption = Annotated[str, typer.Option(
    "--recall-at", help=f"N of Recall@N (a true match among the N best-ranked map frames; runs that rank the map), "
                        f"comma-separated, each 1 to {RANKED}, such as 1,5,10,20.")]
RECALL_AT_TEXT = ",".join(map(str, RANKED_KS))
FramesOption = Annotated[Optional[str], typer.Option(
    "--frames", metavar="SLICE", show_default="every frame",
    help="Score only a slice of each run's frames, counted in the run's order, as Python slices a list: 20: (from "
         "the 21st frame on), :20 (the first 20), 100:300; a negative number counts from the end.")]


def parse_recall_at(text: str) -> list[int]:
    """`--recall-at 1,5,10,20`: whole numbers from 1 to the ranking's length; anything else is a
    usage error."""
    parts = [part.strip() for part in text.split(",") if part.strip()]
    if not parts or not all(part.isdigit() and 1 <= int(part) <= RANKED for part in parts):
        fail(f"--recall-at: '{text}': give whole numbers from 1 to {RANKED} (results keep the {RANKED} best "
             "candidates), comma-separated, such as 1,5,10,20", EXIT_USAGE)
    return sorted({int(part) for part in parts})


def parse_cuts(text: str) -> list[float]:
    """`--cuts 0.5,0.9,0.99`: numbers in [0, 1], each once and in order, as ``--recall-at``'s N
    (a cut given twice was a table row and a JSON entry twice, but one CSV column); anything
    else is a usage error."""
    try:
        cuts = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        cuts = []
    if not cuts or not all(0.0 <= cut <= 1.0 for cut in cuts):
        fail(f"--cuts: '{text}': give confidences in [0, 1], comma-separated, such as {CUTS_TEXT}", EXIT_USAGE)
    from wiloc.evaluation.comparison import check_cuts  # pandas: loaded by the work, not by --help

    return check_cuts(cuts)


def scored_frames(evaluations: list[api.Evaluation]) -> list[str]:
    """A line per run scored on a slice of its frames (``--frames``) saying which, and of how many;
    none when every frame was scored."""
    return [f"{e.path or e.name}: frames {e.frame_slice} of {e.run_frames} scored ({e.summary.frames} frames)"
            for e in evaluations if e.frame_slice is not None]


def slice_columns(evaluation: api.Evaluation) -> dict[str, Any]:
    """A run's ``frame_slice`` and ``run_frames`` for its table row, CSV row and --json, when it was
    scored on a slice of its frames (``--frames``); none when every frame was scored."""
    e = evaluation
    return {} if e.frame_slice is None else {"frame_slice": e.frame_slice, "run_frames": e.run_frames}


def slice_key(evaluations: list[api.Evaluation]) -> dict[str, str]:
    """The --json's ``frame_slice``: the slice of each run's frames scored (``--frames``, one for all
    runs); none when every frame was scored."""
    frames = evaluations[0].frame_slice
    return {} if frames is None else {"frame_slice": frames}


def warn_about_truth(evaluations: list[api.Evaluation]) -> Notes:
    """Name-matching warnings, and runs whose ground truth leaves nothing to recall."""
    notes = Notes()
    for e in evaluations:
        for doubt in e.truth_doubts:
            notes.add("warning", f"{e.path}: {doubt}")
    return notes


def curves_file(path: Path) -> Path:
    """Where the curves go beside the metrics CSV ``path``: ``<stem>-curves.csv``."""
    return path.with_name(path.stem + "-curves.csv")


def metrics_outputs(value: Path | None) -> list[Path]:
    """The files ``--csv FILE`` writes: the metrics and their curves beside them (none without it)."""
    return [] if value is None else [value, curves_file(value)]


def metrics_file(value: Path | None) -> Path | None:
    """``--csv FILE``, checked before any work: one file (:func:`one_file`), and nothing but a
    file where its curves go beside it, so that neither is left written without the other."""
    if one_file(value) is not None and (problem := output_problem(curves_file(value))) is not None:
        raise typer.BadParameter(f"{curves_file(value)} (the curves beside it): {problem}")
    return value


def write_metrics_csv(path: Path, rows: list[dict[str, Any]], evaluations: list[api.Evaluation],
                      notes: Notes) -> list[Path]:
    """The metrics to ``path`` and the curves to ``<stem>-curves.csv`` beside it, both naming each
    run by its results file as given (``results``, the column that joins them); a file replaced
    is said so. Returns both paths."""
    import pandas as pd

    curves_path = curves_file(path)
    records = [{**row, "results": str(e.path)} for row, e in zip(rows, evaluations, strict=True)]
    metrics = pd.DataFrame(records)
    for column in metrics.columns:  # a count missing from a run (no new_place column) made its column float
        present = [r[column] for r in records if r.get(column) is not None]
        if present and all(_is_count(value) for value in present):
            metrics[column] = metrics[column].astype("Int64")  # written as 5, empty where missing
    curves = pd.concat([pd.DataFrame({"results": str(e.path), "threshold": e.curve.thresholds,
                                      "precision": e.curve.precision, "recall": e.curve.recall})
                        for e in evaluations])
    for target, frame in ((path, metrics), (curves_path, curves)):
        with written_whole(replacing(notes, target), "the metrics file") as file:
            frame.to_csv(file, index=False)
    return [path, curves_path]


def _is_count(value: Any) -> bool:
    """Whether a metrics value is a whole count (an int, numpy's too; not a bool)."""
    import numpy as np

    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
