"""`wiloc vocabulary`: the local features of training folders clustered into visual words, kept
in the cache for bow and FAB-MAP."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from wiloc.cli.core import Notes, fail, handles_errors, out, print_line
from wiloc.cli.options import CacheOption, TrainingJobsOption
from wiloc.cli.params import with_vocabulary_options
from wiloc.cli.views import print_command_json, progress_bar, table
from wiloc.errors import EXIT_USAGE


@handles_errors
@with_vocabulary_options
def vocabulary(
    folders: list[Path] = typer.Argument(..., metavar="FOLDER...", help="Training image folders (never the pair you will test on)."),
    cache: CacheOption = None,
    jobs: TrainingJobsOption = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
    vocabulary_options: dict[str, Any] | None = None,
) -> None:
    """Cluster the local features of training folders into a visual vocabulary for bow and FAB-MAP.

    The vocabulary is kept in the cache.

    Example: wiloc vocabulary data/night_right --words 1000, then
    wiloc localize data/day_left --map data/day_right --descriptor bow --vocabulary KEY --method fabmap
    """
    from wiloc import api
    from wiloc.cache.store import Cache

    seen = [folder.resolve() for folder in folders]
    twice = next((folder for folder, path in zip(folders, seen) if seen.count(path) > 1), None)
    if twice is not None:
        fail(f"FOLDER...: {twice} is given twice (its images would count twice in the clustering)", EXIT_USAGE)
    params = vocabulary_options or {}
    with progress_bar(not as_json) as progress:
        report = api.vocabulary(folders, params, cache=Cache(cache), progress=progress, jobs=jobs)
    notes = Notes()
    for line in report.repairs:
        notes.add("note", line)
    for path, reason in report.failed:  # resolved paths, as --json names frames
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
                    digits={"seconds": 1}))
    print_line(f"in {report.path.parent}")
