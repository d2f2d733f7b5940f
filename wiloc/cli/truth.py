"""The `--gt` grammar: a ground-truth form and its file as the command line names them, made into
the library's :class:`wiloc.evaluation.truth_source.TruthSource`; options that another form would use are
refused."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from wiloc.cli.core import fail, refuse_unused
from wiloc.errors import EXIT_USAGE, ParameterError

if TYPE_CHECKING:
    from wiloc import api

NAMED_FORMS = ("aligned", "utm-names", "exif")  # forms without a file
FORMS = "aligned, aligned:index, positions:Q.csv, pairs:P.csv, matrix:M.npy, vprbench:G.npy, positives:P.npy, utm-names, exif"


def truth_source(gt: str, gt_ref: str | None, tolerance: int, radius: float | None,
                 prefix: str = "") -> api.TruthSource:
    """`--gt` is a form name without a file (aligned, utm-names, exif) or KIND:PATH (positions:q.csv,
    pairs:p.csv, matrix:m.npy, vprbench:g.npy, positives:p.npy), or a path whose suffix tells the form; a
    path that exists or names a folder is one whole, colons and all (``10:00/gt.csv``). Options of another
    form are refused (``prefix``: the options' name prefix, ``train_`` for the trained method's)."""
    from wiloc import api
    from wiloc.evaluation.groundtruth import KINDS
    from wiloc.evaluation.truth_source import file_form

    flag = f"--{prefix.replace('_', '-')}gt"
    kind, sep, path = gt.partition(":")
    if not sep or (kind not in KINDS and (Path(gt).exists() or any(c in kind for c in "/\\"))):  # a path: 10:00/gt.csv
        if gt not in NAMED_FORMS and not Path(gt).is_file() and "{query}" not in gt:
            fail(f"{flag}: '{gt}' is neither a ground-truth form nor a file (forms: {FORMS})", EXIT_USAGE)
        kind, path = (gt, "") if gt in NAMED_FORMS else (file_form(gt), gt)
    if kind not in KINDS:
        fail(f"{flag}: unknown ground-truth form '{kind}' in '{gt}' (forms: {FORMS})", EXIT_USAGE)
    refuse_unused({f"{prefix}tolerance": (kind == "aligned", "--gt aligned (pairs files carry their own)"),
                   f"{prefix}gt_map": (kind == "positions", "positions ground truth"),
                   f"{prefix}radius": (kind in ("positions", "utm-names", "exif"), "positions, utm-names and exif ground truth")})
    by = "name"
    if kind == "aligned" and path in ("name", "index"):  # aligned:index, by index
        by, path = path, ""
    if kind in NAMED_FORMS and path:
        fail(f"{flag}: '{kind}' reads the traversals themselves and takes no file ('{gt}')", EXIT_USAGE)
    variable = None
    if kind == "matrix" and (".mat:" in path or ".npz:" in path):  # matrix:M.mat:NAME picks one array of several
        path, variable = path.rsplit(":", 1)
    try:
        return api.TruthSource(kind=kind, path=path or None, ref_path=gt_ref, tolerance=tolerance, radius=radius,
                               variable=variable, by=by)
    except ParameterError as exc:  # named as typed: --train-radius for the training pair's
        raise ParameterError(f"{prefix}{exc.parameter}", exc.problem) from None


GT_HELP = ("Ground truth: 'aligned' (same file name, +-tolerance frames; 'aligned:index': same index, "
           "a video's frame by its index in the video, as for a video against a folder of its frames), 'positions:Q.csv' (with "
           "--gt-map R.csv), 'pairs:P.csv' or 'matrix:M.npy|.csv|.mat|.npz' ('matrix:M.mat:NAME' or 'matrix:M.npz:NAME' picks one array of several), 'vprbench:ground_truth_new.npy' (VPR-Bench), 'positives:P.npy' (reference indices per query), "
           "'utm-names' (@UTM_east@UTM_north@ file names) or 'exif' (the images' GPS EXIF), these two within --radius "
           "metres (default 25). '{query}' in a path is replaced by the query folder's name.")
GtOption = Annotated[str, typer.Option("--gt", help=GT_HELP)]
GtMapOption = Annotated[Optional[str], typer.Option("--gt-map", help="positions: the reference's positions CSV.")]
ToleranceOption = Annotated[int, typer.Option("--tolerance", "-T", min=0, help="aligned: same place within +-T frames (published evaluations use 2).")]
RadiusOption = Annotated[Optional[float], typer.Option("--radius", help="positions, utm-names, exif: same place within this many metres (utm-names, exif: default 25).")]
