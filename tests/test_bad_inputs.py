"""Bad inputs through the command line: each ends in exactly one stderr line starting ``error:``,
the documented exit code (1 bad input, 2 usage, 3 cache busy, 130 interrupted), no traceback and
nothing half-written. Bad frames inside a folder are skipped with a note, not fatal.

Usage errors are checked before any work: the tests give them files that do not exist, or ask
for outputs that must not appear. Where the entry point matters (Ctrl-C while loading) the
console script runs in a subprocess.
"""
from __future__ import annotations

import ast
import errno
import functools
import json
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import time
import warnings
import zlib
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
from helpers import ends_in_one_error, places, write_traversal
from typer.testing import CliRunner

from wiloc.cache import store as cache_module
from wiloc.cache.store import Cache
from wiloc.cli import app
from wiloc.description.distances import DifferencesTo
from wiloc.errors import FrameError, ParameterError, WilocError
from wiloc.localization.localizer import Localizer

runner = CliRunner()


@pytest.fixture
def route(tmp_path: Path, cache_dir: Path) -> tuple[Path, Path]:
    """A reference and a query over the same 30 places (img0.png ... img29.png)."""
    scenes = places(30)
    return (write_traversal(tmp_path / "ref", scenes, 1.0, 1),
            write_traversal(tmp_path / "query", scenes, 0.7, 2))


@pytest.fixture
def results(route: tuple[Path, Path], tmp_path: Path) -> Path:
    """A threshold run of the query against the reference."""
    ref, query = route
    out = tmp_path / "run.csv"
    assert runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold",
                               "--out", str(out), "--jobs", "1"]).exit_code == 0
    return out


# ------------------------------------------------------------------------------- 2: usage errors

USAGE = {
    "missing argument": (["localize"], "QUERY...: missing (usage: wiloc localize [OPTIONS] QUERY...)"),
    "missing results": (["evaluate"], "RESULTS...: missing"),
    "not a number": (["localize", "Q", "--particles", "abc"], "--particles: input should be a valid integer"),
    "unknown option": (["localize", "Q", "--partcles", "3"], "--partcles: no such option of wiloc localize"),
    "unknown command": (["frob"], "frob: no such command (describe, vocabulary, localize, evaluate, compare, report, demo)"),
    "option without value": (["localize", "Q", "--out"], "--out: needs a value"),
    "flag with value": (["describe", "F", "--json=3"], "--json: takes no value"),
    "negative tolerance": (["evaluate", "R", "--tolerance", "-1"], "--tolerance: input should be greater"),
    "negative training tolerance": (["localize", "Q", "--method", "trained", "--train-query", "T", "--train-map", "M",
                                     "--train-gt", "aligned", "--train-tolerance", "-1"], "--train-tolerance: input should be greater"),
    "nothing to describe": (["describe"], "FOLDER...: give image folders"),
    "list with folders": (["describe", "--list", "F"], "--list: shows what the cache holds"),
    "list of one descriptor": (["describe", "--list", "--descriptor", "gist", "--json"],
                               "--descriptor: does not go with --list, which takes --cache and --json only"),
    "list with a descriptor option": (["describe", "--list", "--crop", "top-half"], "--crop: does not go with --list"),
    "list descriptors with jobs": (["describe", "--list-descriptors", "--jobs", "2"],
                                   "--jobs: does not go with --list-descriptors, which takes --json only"),
    "unknown method": (["localize", "Q", "--method", "nope"], "--method: unknown method 'nope'"),
    "unknown metric": (["localize", "Q.npy", "--map", "M.npy", "--metric", "cosinus"],
                       "--metric: 'cosinus' is no metric; give one of l1, sqeuclidean, hamming, cosine"),
    "unknown metric to import": (["describe", "--import", "Q.npy", "--metric", "L1"], "--metric: 'L1' is no metric"),
    "bad precision": (["compare", "R", "--precision", "abc"], "--precision: 'abc'"),
    "bad cuts": (["evaluate", "R", "--cuts", "1.5"], "--cuts: '1.5'"),
    "recall at 0": (["evaluate", "R", "--recall-at", "0,5"], "--recall-at: '0,5': give whole numbers from 1 to 20"),
    "recall beyond the ranking": (["compare", "R", "--recall-at", "50"], "--recall-at: '50'"),
    "markdown and latex": (["compare", "R", "--markdown", "--latex"], "--latex: give one of --markdown, --latex and --json"),
    "compare csv in a missing folder": (["compare", "R", "--csv", "nowhere/m.csv"], "--csv: the folder nowhere does not exist"),
    "one file for two figures": (["compare", "R", "--pr-plot", "f.png", "--calibration-plot", "f.png"],
                                 "--calibration-plot: f.png is --pr-plot's file; give each output a file of its own"),
    "metrics over a results file": (["evaluate", "R.csv", "--csv", "R.csv"],
                                    "--csv: R.csv is one of the results files read; give each output a file of its own"),
    "misspelt form": (["evaluate", "R", "--gt", "alined"], "--gt: 'alined' is neither a ground-truth form"),
    "unknown form": (["evaluate", "R", "--gt", "foo:bar.csv"], "--gt: unknown ground-truth form 'foo'"),
    "plot suffix": (["evaluate", "R", "--pr-plot", "pr.pgn"], "--pr-plot: '.pgn' is not a figure format"),
    "plot without suffix": (["compare", "R", "--threshold-plot", "fig5"], "--threshold-plot: the name has no suffix"),
    "model plot suffix": (["localize", "Q", "--model-plot", "m.xyz"], "--model-plot: '.xyz'"),
    "matrix plot suffix": (["evaluate", "R", "--matrix-plot", "m.jpgg"], "--matrix-plot: '.jpgg'"),
    "idle without follow": (["localize", "Q", "--idle", "3"], "--idle: applies to --follow only"),
    "jobs on a remote cluster": (["describe", "Q", "--scheduler", "tcp://127.0.0.1:1", "--jobs", "2"],
                                 "--jobs: applies to image folders described on this machine or a local Dask cluster "
                                 "(--scheduler local) only"),
    "localize jobs on a remote cluster": (["localize", "Q", "--scheduler", "tcp://127.0.0.1:1", "--jobs", "2"],
                                          "--jobs: applies to image folders, video files and ROS bags described on "
                                          "this machine, and a local Dask cluster (--scheduler local) only"),
    "partial training": (["localize", "Q", "--method", "trained", "--train-query", "T"],
                         "--train-map: missing; --train-query, --train-map and --train-gt go together"),
    "training for online": (["localize", "Q", "--train-query", "T"],
                            "--train-query: applies to the methods trained on a labelled pair (trained) only"),
    "seed out of range": (["localize", "Q", "--method", "catgraph", "--seed", "-1"], "--seed: must be >= 0"),
    "too many particles": (["localize", "Q", "--method", "catgraph", "--particles", "1000000000"], "--particles: must lie in"),
    "too many bins": (["localize", "Q", "--bins", "100000000"], "--bins: must lie in"),
    "option of another method": (["localize", "Q", "--particles", "5"], "--particles: method 'online' takes no such option"),
    "exclude recent": (["localize", "Q", "-R", "-1"], "--exclude-recent: must be an integer >= 0"),
    "radius with aligned": (["evaluate", "R", "--radius", "3"], "--radius: applies to positions, utm-names and exif ground truth only"),
    "gt map with aligned": (["evaluate", "R", "--gt-map", "m.csv"], "--gt-map: applies to positions ground truth only"),
    "csv in a missing folder": (["evaluate", "R", "--csv", "nowhere/m.csv"], "--csv: the folder nowhere does not exist (create it first)"),
    "plot in a missing folder": (["evaluate", "R", "--pr-plot", "no/where/pr.png"], "--pr-plot: the folder no/where does not exist"),
    "out in a missing folder": (["localize", "Q", "-o", "nowhere/run.csv"], "--out: the folder nowhere does not exist"),
    # an unset shell variable ("$MAP") makes an empty path, which pathlib reads as the current folder
    "empty results file": (["evaluate", ""], "RESULTS...: an empty path; give a file or folder"),
    "empty folder among several": (["describe", "F", ""], "FOLDER...: an empty path"),
    "empty map": (["localize", "Q", "--map", ""], "--map: an empty path"),
    "empty cache": (["describe", "F", "--cache="], "--cache: an empty path"),
    "empty results out": (["localize", "Q", "-o", ""], "--out: an empty path; give a file or folder"),
}


@pytest.mark.parametrize("case", USAGE)
def test_usage_errors_are_one_line_before_any_work(case: str, tmp_path: Path, cache_dir: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # relative names: nothing exists, nothing may be written
    args, message = USAGE[case]
    ends_in_one_error(runner.invoke(app, args), 2, message)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


UNUSED = {
    "crop with gist": (["describe", "{ref}", "--descriptor", "gist", "--crop", "top-half"], "--crop: applies to --descriptor sad only"),
    "metric with folders": (["localize", "{query}", "--map", "{ref}", "--metric", "cosine"], "--metric: applies to descriptor matrix files"),
    "crop with gist to localize": (["localize", "{query}", "--map", "{ref}", "--descriptor", "gist", "--crop", "top-half"],
                                   "--crop: applies to --descriptor sad only"),
    "vocabulary without bow": (["localize", "{query}", "--map", "{ref}", "--vocabulary", "v"], "--vocabulary: applies to --descriptor bow only"),
    "map names for a folder": (["localize", "{query}", "--map", "{ref}", "--map-names", "n.txt"], "--map-names: applies to a descriptor matrix file as --map"),
    "sampling to localize folders": (["localize", "{query}", "--map", "{ref}", "--fps", "2"], "--fps: applies to video files and ROS bags only"),
    "training options without a pair": (["localize", "{query}", "--map", "{ref}", "--train-tolerance", "3"],
                                        "--train-tolerance: applies to a training pair"),
    "precision without table II": (["compare", "{tmp}/none.csv", "--no-global-threshold", "--precision", "90"],
                                   "--precision: applies to Table II (--global-threshold) only"),
    "metric without import": (["describe", "{ref}", "--metric", "cosine"], "--metric: applies to --import only"),
    "names without import": (["describe", "{ref}", "--names", "n.txt"], "--names: applies to --import only"),
    "names for a folder": (["localize", "{query}", "--map", "{ref}", "--names", "n.txt"], "--names: applies to a descriptor matrix file"),
    "sampling with import": (["describe", "--import", "{ref}/x.npy", "--every", "2"], "--every: applies to video files and ROS bags only"),
    "descriptor with import": (["describe", "--import", "{ref}/x.npy", "--descriptor", "gist"],
                               "--descriptor: applies to image folders, video files and ROS bags only"),
    "sampling with a folder": (["describe", "{ref}", "--every", "2"], "--every: applies to video files and ROS bags only"),
    "cut of a folder": (["describe", "{ref}", "--stop", "5"], "error: --stop: applies to video files and ROS bags only"),
    "map odometry in sequence mode": (["localize", "{query}", "--method", "catgraph", "--map-odometry", "{tmp}/o.csv"],
                                      "--map-odometry: applies to map mode (--map) only"),
    "one odometry log for two queries": (["localize", "{query}", "{ref}", "--map", "{ref}", "--method", "catgraph",
                                          "--odometry", "{tmp}/o.csv", "--map-odometry", "{tmp}/o.csv"],
                                         "--odometry: the log of one query; give one QUERY with it"),
    "odometry of a method without it": (["localize", "{query}", "--method", "online", "--odometry", "{tmp}/o.csv"],
                                        "--odometry: method 'online' takes no odometry"),
    "query odometry without the map's": (["localize", "{query}", "--map", "{ref}", "--method", "catgraph",
                                          "--odometry", "{tmp}/o.csv"],
                                         "--map-odometry: the query's odometry needs the map's too"),
    "online's init against a map": (["localize", "{query}", "--map", "{ref}", "--method", "online", "--init", "5"],
                                    "--init: applies to sequence mode (no map) only"),
    "catgraph's frontier against a map": (["localize", "{query}", "--map", "{ref}", "--method", "catgraph",
                                           "--frontier", "5"], "--frontier: applies to sequence mode (no map) only"),
    "catgraph's odometry scale without odometry": (["localize", "{query}", "--map", "{ref}", "--method", "catgraph",
                                                    "--odometry-scale", "0.1"],
                                                   "--odometry-scale: applies to a run with the query's odometry only"),
    "follow with the map's odometry": (["localize", "{query}", "--map", "{ref}", "--method", "catgraph", "--follow",
                                        "--map-odometry", "{tmp}/o.csv"],
                                       "--follow: takes one query folder and not --map-odometry"),
    "follow with an odometry-only parameter": (["localize", "{query}", "--method", "catgraph", "--follow",
                                                "--odometry-scale", "0.1"],
                                               "--odometry-scale: applies to a run with the query's odometry only"),
    "map odometry without the query's": (["localize", "{query}", "--map", "{ref}", "--method", "catgraph",
                                          "--map-odometry", "{tmp}/o.csv"],
                                         "--map-odometry: the map's odometry is used only with the query's"),
    "external descriptor of images": (["localize", "{query}", "--map", "{ref}", "--descriptor", "external"],
                                      "--descriptor: 'external' names imported descriptor matrices, which are not described"),
    "external descriptor to describe": (["describe", "{ref}", "-d", "external"],
                                        "--descriptor: 'external' names imported descriptor matrices"),
    "recent window against a map": (["localize", "{query}", "--map", "{ref}", "--method", "threshold", "-R", "3"],
                                    "--exclude-recent: applies to sequence mode, and in map mode to the methods that "
                                    "learn from the map's differences to itself (online) only"),
    "model plot of a method without one": (["localize", "{query}", "--map", "{ref}", "--method", "catgraph",
                                            "--model-plot", "{tmp}/m.png"], "--model-plot: method 'catgraph' learns no"),
    "model plot of several queries": (["localize", "{query}", "{ref}", "--map", "{ref}", "--out", "{tmp}/runs/",
                                       "--model-plot", "{tmp}/m.png"], "--model-plot: draws one run's histograms"),
    "jobs below one": (["describe", "{ref}", "--jobs", "0"], "--jobs: must be at least 1"),
    "several queries one file": (["localize", "{query}", "{ref}", "--map", "{ref}", "--out", "{tmp}/o.csv"], "with several queries --out names a folder"),
}


@pytest.mark.parametrize("case", UNUSED)
def test_options_the_input_does_not_use_are_refused(case: str, route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    args, message = UNUSED[case]
    args = [a.format(ref=ref, query=query, tmp=tmp_path) for a in args]
    ends_in_one_error(runner.invoke(app, args), 2, message)
    assert not (tmp_path / "o.csv").exists() and not list(tmp_path.glob("*.csv"))


# --------------------------------------------------------------------------- 1: bad input files

def _huge_png(path: Path) -> Path:
    """A PNG whose header says 40000 x 40000 pixels: over OpenCV's decode limit."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 40000, 40000, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(b"\0" * 16)) + chunk(b"IEND", b""))
    return path


def _h5_with_names(path: Path, names: list[bytes]) -> Path:
    with h5py.File(path, "w") as f:
        f["descriptors"] = np.random.default_rng(0).random((len(names), 4)).astype(np.float32)
        f["names"] = np.array(names, dtype=object).astype("S")
    return path


def _case_files(tmp: Path, ref: Path, results: Path) -> dict[str, tuple[list[str], str]]:
    """Each bad-input case: its arguments and a fragment of its one error line."""
    (tmp / "empty").mkdir()
    (tmp / "notes.txt").write_text("not images\n")
    (tmp / "bad-only").mkdir()
    (tmp / "bad-only" / "a.png").write_bytes(b"")
    (tmp / "bad-only" / "b.jpg").write_bytes(b"\xff\xd8 cut")
    np.save(tmp / "nan.npy", np.full((5, 4), np.nan, np.float32))
    np.save(tmp / "text-gt.npy", np.array([["yes", "no"]] * 2))
    np.save(tmp / "shape-gt.npy", np.eye(3))
    (tmp / "pairs.csv").write_text("a,b\nimg0.png,img0.png\n")
    (tmp / "x.mp4").write_text("no video\n" * 50)
    lines = results.read_text().splitlines()
    confidence = lines.index(next(l for l in lines if l.startswith("frame,"))) + 1
    row = lines[confidence].split(",")
    row[3] = "high"
    (tmp / "text-confidence.csv").write_text("\n".join(lines[:confidence] + [",".join(row)] + lines[confidence + 1:]) + "\n")
    (tmp / "single").mkdir()
    (tmp / "single" / "img0.png").write_bytes((ref / "img0.png").read_bytes())
    (tmp / "links").mkdir()
    (tmp / "links" / "a.png").symlink_to(tmp / "gone.png")
    (tmp / "odo.csv").write_text("name,distance\nimg0.png,0\n")
    np.save(tmp / "objects.npy", np.array([{"a": 1}], dtype=object))
    (tmp / "v99.csv").write_text(results.read_text().replace("# wiloc-results: 1\n", "# wiloc-results: 99\n", 1))
    return {
        "missing folder": (["describe", str(tmp / "nope")], "folder does not exist"),
        "a text file": (["describe", str(tmp / "notes.txt")], "a .txt file is not a traversal: describe takes folders"),
        "no images": (["describe", str(tmp / "empty")], "no image files"),
        "only broken links": (["describe", str(tmp / "links")], "no usable image files (a.png: broken symbolic link)"),
        "only bad images": (["describe", str(tmp / "bad-only"), "--jobs", "1"], "no image could be described"),
        "h5 names not utf-8": (["describe", "--import", str(_h5_with_names(tmp / "n.h5", [b"a", b"\xff\xfe"]))],
                               "entry 2: b'\\xff\\xfe' is not UTF-8 text"),
        "nan descriptors": (["describe", "--import", str(tmp / "nan.npy")], "NaN or infinite value in row 1"),
        "missing matrix": (["describe", "--import", str(tmp / "none.npy")], "file does not exist"),
        "unknown matrix format": (["describe", "--import", str(tmp / "notes.txt")], "unknown matrix format"),
        "not a video": (["describe", str(tmp / "x.mp4")], "not a video wiloc can read"),
        "missing results": (["evaluate", str(tmp / "none.csv")], "results file does not exist"),
        "foreign csv": (["evaluate", str(tmp / "pairs.csv")], "not a wiloc results file"),
        "text confidence": (["evaluate", str(tmp / "text-confidence.csv")], "confidence 'high' is not a number"),
        "text ground truth": (["evaluate", str(results), "--gt", f"matrix:{tmp / 'text-gt.npy'}"],
                              "matrix holds <U3 values; give numbers"),
        "ground truth shape": (["evaluate", str(results), "--gt", f"matrix:{tmp / 'shape-gt.npy'}"], "matrix is 3 x 3"),
        "pairs columns": (["evaluate", str(results), "--gt", f"pairs:{tmp / 'pairs.csv'}"], "missing column(s) query, reference"),
        "positions file": (["evaluate", str(results), "--gt", f"positions:{tmp / 'none.csv'}", "--gt-map", str(tmp / "none.csv"),
                            "--radius", "2"], "file does not exist"),
        "map of one frame": (["localize", str(ref), "--map", str(tmp / "single")], "it needs at least 2"),
        "odometry": (["localize", str(ref), "--map", str(ref), "--method", "catgraph", "--odometry", str(tmp / "odo.csv"),
                      "--map-odometry", str(tmp / "odo.csv")], "no odometry for 29 frame(s)"),
        "odometry folder": (["localize", str(ref), "--map", str(ref), "--method", "catgraph", "--odometry", str(tmp),
                             "--map-odometry", str(tmp)], f"error: {tmp}: a folder, not an odometry CSV file"),
        "missing odometry": (["localize", str(ref), "--map", str(ref), "--method", "catgraph", "--odometry",
                              str(tmp / "none.csv"), "--map-odometry", str(tmp / "none.csv")],
                             f"error: {tmp / 'none.csv'}: file does not exist"),
        "results format version": (["evaluate", str(tmp / "v99.csv")], "line 1: results format version '99' is not "
                                   "one this wiloc reads (it reads 1)"),
        "an image as map": (["localize", str(ref), "--map", str(ref / "img0.png")],
                            f"{ref / 'img0.png'}: an image file is not a traversal: give a folder of images, a video"),
        "object array": (["describe", "--import", str(tmp / "objects.npy")],
                         "not a readable .npy array (holds Python objects, not a plain numeric array)"),
        "object array ground truth": (["evaluate", str(results), "--gt", f"matrix:{tmp / 'objects.npy'}"],
                                      "cannot read matrix (holds Python objects, not a plain numeric array)"),
    }


CASES = ("missing folder", "a text file", "no images", "only broken links", "only bad images", "h5 names not utf-8", "nan descriptors",
         "missing matrix", "unknown matrix format", "not a video", "missing results", "foreign csv", "text confidence",
         "text ground truth", "ground truth shape", "pairs columns", "positions file", "map of one frame", "odometry",
         "odometry folder", "missing odometry", "results format version", "an image as map", "object array",
         "object array ground truth")


@pytest.mark.parametrize("case", CASES)
def test_bad_input_files_are_one_line_with_exit_code_1(case: str, route: tuple[Path, Path], results: Path,
                                                      tmp_path: Path) -> None:
    ref, _ = route
    args, message = _case_files(tmp_path, ref, results)[case]
    ends_in_one_error(runner.invoke(app, args), 1, message)
    assert not (tmp_path / "fig1.png").exists()


def test_an_unreadable_folder_is_exit_code_1(route: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    ref, _ = route
    scandir = os.scandir

    def refuse(path):  # as a folder without read permission does (the tests may run as root)
        if Path(path) == ref:
            raise PermissionError(13, "Permission denied", str(path))
        return scandir(path)
    monkeypatch.setattr(os, "scandir", refuse)
    ends_in_one_error(runner.invoke(app, ["describe", str(ref)]), 1, f"{ref}: Permission denied")


def test_an_image_over_the_pixel_limit_is_skipped_like_any_bad_frame(route: tuple[Path, Path]) -> None:
    ref, _ = route
    _huge_png(ref / "img99.png")
    for jobs in ("1", "2"):
        result = runner.invoke(app, ["describe", str(ref), "--jobs", jobs, "--json"])
        assert result.exit_code == 0, result.output
        report = json.loads(result.stdout)
        [row] = report["results"]
        assert (row["frames"], row["failed"]) == (31, 1)
        assert report["warnings"] == [f"skipped: {ref / 'img99.png'}: image over OpenCV's size limit (2^30 pixels; "
                                   "the environment variable OPENCV_IO_MAX_IMAGE_PIXELS raises it)"]
        assert result.stderr.strip().startswith("skipped ") and "Traceback" not in result.output


def test_a_run_whose_folders_changed_cannot_be_drawn(route: tuple[Path, Path], results: Path, tmp_path: Path) -> None:
    _, query = route
    (query / "img3.png").unlink()
    (query / "img5.png").write_bytes(b"")  # there, but no longer an image: not "gone"
    cv2.imwrite(str(query / "img30.png"), cv2.imread(str(query / "img0.png")))
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), "--matrix-plot", str(tmp_path / "m.png")]), 1,
                      f"{results}: its query {query} no longer gives the frames it lists (img3.png gone; img5.png "
                      "unreadable now; img30.png new); cannot draw it")
    assert not (tmp_path / "m.png").exists()


def test_a_matrix_plot_of_a_run_whose_map_is_gone_names_the_run(route: tuple[Path, Path], results: Path,
                                                                  tmp_path: Path) -> None:
    """It said only "MAP: folder does not exist": with several results files, not which run."""
    reference, _ = route
    reference.rename(tmp_path / "moved")
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), "--matrix-plot", str(tmp_path / "m.png")]), 1,
                      f"{results}: its traversal {reference} does not exist (moved or deleted); cannot draw it")


def test_example_pairs_need_image_folders(tmp_path: Path, cache_dir: Path) -> None:
    rng = np.random.default_rng(0)
    for name in ("q", "r"):
        np.save(tmp_path / f"{name}.npy", rng.random((12, 8)).astype(np.float32))
    out = tmp_path / "run.csv"
    assert runner.invoke(app, ["localize", str(tmp_path / "q.npy"), "--map", str(tmp_path / "r.npy"), "--metric",
                               "cosine", "--method", "threshold", "--out", str(out)]).exit_code == 0
    ends_in_one_error(runner.invoke(app, ["evaluate", str(out), "--gt", "aligned", "--gt", "aligned",
                                          "--pairs-plot", str(tmp_path / "p.png")]), 1, "need the image folders")


def test_csv_and_figures_say_which_files_they_replaced(results: Path, tmp_path: Path) -> None:
    (tmp_path / "m-curves.csv").write_text("old\n")
    (tmp_path / "pr.png").write_bytes(b"old")
    result = runner.invoke(app, ["evaluate", str(results), "--csv", str(tmp_path / "m.csv"), "--json",
                                 "--pr-plot", str(tmp_path / "pr.png"), "--calibration-plot", str(tmp_path / "c.png")])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    replaced = [tmp_path / "pr.png", tmp_path / "m-curves.csv"]
    assert report["warnings"] == [f"note: replaced the existing file {path}" for path in replaced]
    assert result.stderr.strip().splitlines() == [f"note replaced the existing file {path}" for path in replaced]
    assert report["files"] == [str(tmp_path / name) for name in ("pr.png", "c.png", "m.csv", "m-curves.csv")]
    assert (tmp_path / "pr.png").read_bytes().startswith(b"\x89PNG")


# ------------------------------------------------------------------------------ damaged cache

def _entry_file(cache_dir: Path, folder: Path) -> Path:
    infos = [i for i in cache_module.Cache(cache_dir).list_entries() if i.folder == str(folder.resolve())]
    return cache_module.Cache(cache_dir).entry_path(infos[0].key)


def _damage(path: Path, dataset: str) -> None:
    with h5py.File(path, "r") as f:
        d = f[dataset]
        offset = d.id.get_offset() if d.chunks is None else d.id.get_chunk_info(0).byte_offset
    with open(path, "r+b") as f:
        f.seek(offset + 64)
        f.write(b"\xde\xad\xbe\xef" * 4)


def test_damaged_descriptors_are_described_again_with_a_note(route: tuple[Path, Path], results: Path,
                                                             cache_dir: Path, tmp_path: Path) -> None:
    ref, query = route
    _damage(_entry_file(cache_dir, ref), "descriptors")
    again = tmp_path / "again.csv"
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold",
                                 "--out", str(again), "--jobs", "1", "--json"])
    assert result.exit_code == 0, result.output
    assert "failed their checksum (the file is damaged); described again" in json.loads(result.stdout)["warnings"][0]
    assert again.read_text().split("frame,")[1] == results.read_text().split("frame,")[1]  # the same decisions


def test_a_damaged_map_summary_is_computed_anew(route: tuple[Path, Path], cache_dir: Path, tmp_path: Path) -> None:
    ref, query = route
    first, again = tmp_path / "first.csv", tmp_path / "again.csv"
    args = ["localize", str(query), "--map", str(ref), "--method", "online", "--jobs", "1", "--out"]
    assert runner.invoke(app, [*args, str(first)]).exit_code == 0
    [summary] = (cache_dir / "differences").glob("*.h5")  # the map's, the one differences file
    _damage(summary, "minima")
    assert runner.invoke(app, [*args, str(again)]).exit_code == 0
    assert again.read_text().split("frame,")[1] == first.read_text().split("frame,")[1]


# ---------------------------------------------------------------------------------- 3: busy

def test_a_busy_entry_is_exit_code_3(route: tuple[Path, Path], cache_dir: Path,
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    ref, _ = route
    assert runner.invoke(app, ["describe", str(ref), "--jobs", "1"]).exit_code == 0
    entry = _entry_file(cache_dir, ref)
    holder = subprocess.Popen([sys.executable, "-c",
                               "import sys, time; from pathlib import Path; from wiloc.cache.store import Cache\n"
                               f"with Cache(Path({str(cache_dir)!r})).lock('descriptors/{entry.name}'):\n"
                               "    print('held', flush=True); time.sleep(30)\n"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        monkeypatch.setattr(cache_module.Cache.__init__, "__defaults__", (None, 0.3))
        ends_in_one_error(runner.invoke(app, ["describe", str(ref)]), 3, f"in use by another wiloc process (pid {holder.pid})")
    finally:
        holder.kill()
        holder.wait()


# ------------------------------------------------------------------------- 130: interrupted

def _console_script() -> Path:
    script = Path(sys.executable).parent / "wiloc"
    if not script.exists():
        pytest.skip("the wiloc console script is not installed beside this interpreter")
    return script


def _wait_for_the_command(pid: int, timeout: float = 30.0) -> None:
    """Until process ``pid`` has mapped numpy's compiled core (Linux's /proc; elsewhere at once):
    the command's own code runs, and its Ctrl-C handler, installed before anything imports numpy,
    is in place. Before that a Ctrl-C lands in the interpreter's own start-up (tens of
    milliseconds, more on a loaded machine), where no program has a handler of its own yet."""
    maps = Path(f"/proc/{pid}/maps")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if "_multiarray_umath" in maps.read_text():
                return
        except OSError:  # no /proc, or the process is gone
            return
        time.sleep(0.002)


@pytest.mark.parametrize("delay", [0.0, 0.15, 0.3, 0.6, 1.0, 2.0])
def test_ctrl_c_at_any_moment_is_one_line_and_exit_code_130(delay: float, route: tuple[Path, Path],
                                                            tmp_path: Path) -> None:
    """From the moment the command's code runs (the command line still loading) to the work
    itself: a million particles keep catgraph busy for seconds."""
    ref, query = route
    out = tmp_path / "run.csv"
    run = subprocess.Popen([str(_console_script()), "localize", str(query), "--map", str(ref), "--method", "catgraph",
                            "--particles", "1000000", "--jobs", "1", "--out", str(out)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_the_command(run.pid)
    time.sleep(delay)
    run.send_signal(signal.SIGINT)
    _, stderr = run.communicate(timeout=120)
    assert run.returncode == 130, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: interrupted"), stderr
    assert not out.exists()


def test_ctrl_c_that_a_library_swallows_still_stops_the_command(route: tuple[Path, Path], tmp_path: Path) -> None:
    """Ctrl-C raised where Python cannot raise it (typer's pydantic, building its validators,
    prints "Exception ignored" and goes on; here an object's __del__ as the command line starts)
    stops the command before its work, as one line and exit code 130."""
    ref, query = route
    out = tmp_path / "run.csv"
    code = ("import sys, wiloc.cli, wiloc.__main__ as entry\n"
            "class Swallowing:\n"
            "    def __del__(self):\n"
            "        raise KeyboardInterrupt\n"
            "parse_and_run = wiloc.cli.run\n"
            "def run(args=None):\n"
            "    Swallowing()\n"
            "    return parse_and_run(args)\n"
            "wiloc.cli.run = run\n"
            "sys.exit(entry.main())\n")
    result = subprocess.run([sys.executable, "-c", code, "localize", str(query), "--map", str(ref), "--method",
                             "catgraph", "--particles", "1000000", "--jobs", "1", "--out", str(out)],
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 130, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: interrupted"), result.stderr
    assert not out.exists()


def assert_stopped_once_printing(result: subprocess.CompletedProcess[str], line: str) -> None:
    """The held Ctrl-C stopped the command (one line, 130) after the work it waited for, whose
    result ``line`` prints: the line was begun (its values are computed before anything is
    written), and it is whole unless the interrupt, delivered again every few milliseconds while
    held, landed inside the print itself, as it can on a loaded machine."""
    assert (result.returncode, result.stderr) == (130, "error: interrupted\n"), result.stderr
    assert result.stdout and line.startswith(result.stdout), result.stdout


@pytest.mark.parametrize(("ignored", "expected"), [(False, (130, "imported True\n", "error: interrupted\n")),
                                                    (True, (0, "imported True\nnot interrupted\n", ""))],
                         ids=["held", "ignored from the start"])
def test_ctrl_c_during_an_import_waits_for_the_import_then_stops_the_command(
        tmp_path: Path, ignored: bool, expected: tuple[int, str, str]) -> None:
    """Ctrl-C that arrives while a module is being imported is held until the import is done
    (raised inside the import system it can leave a module lock held, so that a later import
    waits forever, or be dropped in its callbacks), then stops the command: one line, 130. A
    command started with Ctrl-C ignored (in the background by a non-interactive shell) runs on
    through it, as Python itself does."""
    (tmp_path / "interrupted_module.py").write_text("import signal\nsignal.raise_signal(signal.SIGINT)\nLOADED = True\n")
    code = ("import signal, sys, time, wiloc.cli, wiloc.__main__ as entry\n"
            + ("signal.signal(signal.SIGINT, signal.SIG_IGN)\n" if ignored else "")
            + "def run(args=None):\n"
            "    import interrupted_module\n"
            "    print('imported', interrupted_module.LOADED, flush=True)\n"
            "    time.sleep(3)\n"
            "    print('not interrupted', flush=True)\n"
            "    return 0\n"
            "wiloc.cli.run = run\n"
            "sys.exit(entry.main())\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                            env={**os.environ, "PYTHONPATH": str(tmp_path)}, check=False)
    if ignored:
        assert (result.returncode, result.stdout, result.stderr) == expected
    else:
        assert_stopped_once_printing(result, expected[1])


def test_ctrl_c_while_numba_compiles_waits_for_the_kernel_then_stops_the_command() -> None:
    """Ctrl-C that arrives while numba compiles a kernel (seconds on its first call with a cold
    cache) is held until the kernel is built (raised inside the compiler, it leaves the kernel
    half-built and surfaces as numba's own error, or not at all), then stops the command: one
    line, 130."""
    code = ("import os, signal, sys, threading, time, numba, wiloc.cli, wiloc.__main__ as entry\n"
            "main = threading.main_thread().ident\n"
            "def in_numba():\n"
            "    frame = sys._current_frames().get(main)\n"
            "    while frame is not None and f'{os.sep}numba{os.sep}' not in frame.f_code.co_filename:\n"
            "        frame = frame.f_back\n"
            "    return frame is not None\n"
            "def interrupt_the_compile():\n"
            "    while not in_numba():\n"
            "        time.sleep(0.0005)\n"
            "    signal.pthread_kill(main, signal.SIGINT)\n"
            "def run(args=None):\n"
            "    kernel = numba.njit(lambda x: x + 1)\n"
            "    threading.Thread(target=interrupt_the_compile, daemon=True).start()\n"
            "    print('compiled', kernel(1), flush=True)\n"
            "    time.sleep(3)\n"
            "    print('not interrupted', flush=True)\n"
            "    return 0\n"
            "wiloc.cli.run = run\n"
            "sys.exit(entry.main())\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert_stopped_once_printing(result, "compiled 2\n")


def test_ctrl_c_after_the_work_leaves_the_exit_code_alone(route: tuple[Path, Path], tmp_path: Path) -> None:
    """A Ctrl-C while the finished process exits (interpreter teardown) neither kills it nor
    prints anything: the command's own exit code stands."""
    code = ("import signal, sys, wiloc.__main__ as entry\n"
            "sys.argv = ['wiloc', '--version']\n"
            "status = entry.main()\n"
            "signal.raise_signal(signal.SIGINT)\n"
            "sys.exit(status)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert (result.returncode, result.stderr) == (0, "")


@pytest.mark.parametrize("args, message", [(["localize", "Q", "--particles", "abc"], "error: --particles: input should"),
                                           (["frob"], "error: frob: no such command"),
                                           (["evaluate"], "error: RESULTS...: missing")])
def test_usage_errors_are_one_line_from_the_console_script_too(args: list[str], message: str, tmp_path: Path) -> None:
    result = subprocess.run([str(_console_script()), *args], capture_output=True, text=True, cwd=tmp_path,
                            timeout=120, check=False)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.splitlines() == [result.stderr.strip()] and result.stderr.startswith(message)


def _closed_output(command: list[str]) -> subprocess.CompletedProcess[str]:
    """``command`` run with its stdout a pipe whose reader has already gone (`... | head`)."""
    reader, writer = os.pipe()
    os.close(reader)
    try:
        return subprocess.run(command, stdout=writer, stderr=subprocess.PIPE, text=True, timeout=120, check=False)
    finally:
        os.close(writer)


@pytest.mark.parametrize("args", [["--help"], ["localize", "--help"], ["--version"], ["evaluate", "RESULTS"],
                                  ["evaluate", "RESULTS", "--json"]])
def test_a_reader_that_closes_the_output_ends_the_command_quietly(args: list[str], results: Path) -> None:
    """`wiloc ... | head`: every print of the command meets the closed pipe."""
    result = _closed_output([str(_console_script()), *[str(results) if a == "RESULTS" else a for a in args]])
    assert (result.returncode, result.stderr) == (1, "")


@pytest.mark.parametrize("args", [["--help"], ["evaluate", "RESULTS"], ["evaluate", "RESULTS", "--json"]])
def test_a_full_disk_under_stdout_is_one_line_naming_it(args: list[str], results: Path) -> None:
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full here")
    with open("/dev/full", "w") as full:
        result = subprocess.run([str(_console_script()), *[str(results) if a == "RESULTS" else a for a in args]],
                                stdout=full, stderr=subprocess.PIPE, text=True, timeout=120, check=False)
    assert (result.returncode, result.stderr) == (1, "error: standard output: No space left on device\n")


def test_follow_ends_quietly_when_the_reader_of_its_rows_has_gone(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    out = tmp_path / "live.csv"
    result = _closed_output([str(_console_script()), "localize", str(query), "--map", str(ref), "--method", "catgraph",
                             "--follow", "--idle", "1", "--out", str(out)])
    assert (result.returncode, result.stderr) == (1, "")


def test_a_command_started_with_stdout_closed_does_its_work(route: tuple[Path, Path], tmp_path: Path) -> None:
    """`wiloc localize ... >&-`: nothing can be printed, the results file is written whole."""
    ref, query = route
    out = tmp_path / "run.csv"
    result = subprocess.run([str(_console_script()), "localize", str(query), "--map", str(ref), "--method", "threshold",
                             "--jobs", "1", "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, timeout=120, preexec_fn=lambda: os.close(1), check=False)
    assert (result.returncode, result.stderr) == (0, "")
    assert len(out.read_text().splitlines()) > 30


def test_a_command_started_with_stderr_closed_does_its_work(tmp_path: Path, cache_dir: Path) -> None:
    """`wiloc describe A B 2>&-`: the descriptor 2 that the command lacks is not taken by a file
    it opens (a cache file), where libjpeg's own warnings would land, or closed under it."""
    scenes = places(60)
    folders = [write_traversal(tmp_path / name, scenes, gain, seed) for name, gain, seed in (("a", 1.0, 1), ("b", 0.7, 2))]
    result = subprocess.run([str(_console_script()), "describe", *map(str, folders), "--jobs", "2", "--json"],
                            stdout=subprocess.PIPE, text=True, timeout=300, preexec_fn=lambda: os.close(2),
                            check=False)
    assert result.returncode == 0
    assert [entry["frames"] for entry in json.loads(result.stdout)["results"]] == [60, 60]


def test_json_is_plain_json_whatever_the_terminal_asks_for(results: Path) -> None:
    """FORCE_COLOR (set by many CI systems) colours tables, never --json; a narrow terminal does
    not wrap it."""
    env = {**os.environ, "FORCE_COLOR": "1", "TTY_COMPATIBLE": "1", "COLUMNS": "20"}
    result = subprocess.run([str(_console_script()), "evaluate", str(results), "--json"], capture_output=True,
                            text=True, timeout=120, env=env, check=False)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["runs"][0]["results"] == str(results)


def test_what_the_output_cannot_encode_is_escaped(route: tuple[Path, Path], tmp_path: Path) -> None:
    """PYTHONIOENCODING=ascii: a help text's "…" and a folder named zürich are printed escaped,
    and --json escapes them as JSON does."""
    ref, _ = route
    folder = tmp_path / "zürich"
    shutil.copytree(ref, folder)
    env = {**os.environ, "PYTHONIOENCODING": "ascii"}
    run = functools.partial(subprocess.run, capture_output=True, text=True, timeout=120, env=env)
    help_text = run([str(_console_script()), "evaluate", "--help"])
    assert help_text.returncode == 0 and "Usage" in help_text.stdout, help_text.stderr
    table = run([str(_console_script()), "describe", str(folder)])
    assert (table.returncode, table.stderr) == (0, "") and "z\\xfcrich" in table.stdout
    described = run([str(_console_script()), "describe", str(folder), "--json"])
    assert json.loads(described.stdout)["results"][0]["folder"] == str(folder)


@pytest.mark.parametrize("output", ["print('x' * 100_000)", "print('x')"])
def test_a_closed_output_met_outside_rich_ends_quietly_too(output: str) -> None:
    """Where the pipe closes after rich's print and before the next one (`wiloc --help | head -1`:
    click writes the rest), or only when the buffered end of the output is flushed."""
    code = ("import sys, wiloc.cli, wiloc.__main__ as entry\n"
            f"def run(args=None):\n    {output}\n    return 0\n"
            "wiloc.cli.run = run\n"
            "sys.exit(entry.main())\n")
    result = _closed_output([sys.executable, "-c", code])
    assert (result.returncode, result.stderr) == (1, "")


# ------------------------------------------------------------- frames left out, each with a line

BAD_NAME = os.fsdecode(b"Image\xff\xfe050.png")  # not UTF-8: held by Python as lone surrogates


def _unusable_frames(folder: Path) -> list[str]:
    """A name that is not UTF-8, a FIFO, a dangling symbolic link and one that loops (to itself),
    each named as an image; the lines that say they were left out."""
    (folder / BAD_NAME).write_bytes((folder / "img0.png").read_bytes())
    os.mkfifo(folder / "Image051.png")
    (folder / "Image052.png").symlink_to(folder / "nowhere.png")
    (folder / "Image053.png").symlink_to("Image053.png")
    return [f"skipped {folder / 'Image051.png'}: not a regular file",
            f"skipped {folder / 'Image052.png'}: broken symbolic link",
            f"skipped {folder / 'Image053.png'}: symbolic link loop",
            f"skipped {folder}/Image\\xff\\xfe050.png: file name is not valid UTF-8; rename the file to use it"]


def _cut_short_frames(folder: Path) -> list[str]:
    """Three more frames of ``folder``, made from its img0.png: a JPEG cut to half its bytes and a
    PNG cut short (decoders fill such images in, or refuse them), and a whole JPEG followed by
    bytes after its end marker (as some cameras write); the lines that say the first two were left out."""
    image = cv2.imread(str(folder / "img0.png"), cv2.IMREAD_GRAYSCALE)
    jpeg, png = (cv2.imencode(suffix, image)[1].tobytes() for suffix in (".jpg", ".png"))
    (folder / "img30.jpg").write_bytes(jpeg[: len(jpeg) // 2])
    (folder / "img31.png").write_bytes(png[: len(png) - 20])
    (folder / "img32.jpg").write_bytes(jpeg + b"\x00" * 512 + b"trailer")
    return [f"skipped {folder / 'img30.jpg'}: truncated JPEG (no end-of-image marker)",
            f"skipped {folder / 'img31.png'}: truncated PNG (no IEND chunk)"]


@pytest.mark.parametrize("unusable", [_unusable_frames, _cut_short_frames], ids=["not frames", "cut short"])
def test_frames_that_cannot_be_read_are_left_out_with_a_line(route: tuple[Path, Path], tmp_path: Path,
                                                              unusable: Callable[[Path], list[str]]) -> None:
    """Names that cannot be frames (not UTF-8, a FIFO, a dangling link, a link that loops) and images cut short: each
    left out with one line, at describe (and under --json) and at localize; the rest decided."""
    ref, query = route
    map_lines = unusable(ref)
    files = len(os.listdir(ref))  # every one named as an image
    result = runner.invoke(app, ["describe", str(ref), "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    [row] = report["results"]
    # frames and failed are the cache entry's (docs/formats.md: /failed records files read and refused); names
    # left out when the folder is listed (no file to record, or no UTF-8 name) are unusable
    left_out = [*row["failed_frames"], *row["unusable"]]
    assert (row["frames"] + len(row["unusable"]), row["failed"], len(left_out), row["shape"][0]) == \
        (files, len(row["failed_frames"]), len(map_lines), files - len(map_lines))
    assert len(row["unusable"]) == (len(map_lines) if unusable is _unusable_frames else 0)
    assert result.stderr.strip().splitlines() == map_lines
    assert len(report["warnings"]) == len(map_lines) and all(w.startswith("skipped: ") for w in report["warnings"])
    query_lines = unusable(query)
    out = tmp_path / "run.csv"
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert sorted(line for line in result.stderr.splitlines() if line.startswith("skipped ")) == sorted(map_lines + query_lines)
    _, *rows = [line for line in out.read_text().splitlines() if not line.startswith("#")]  # the column names, the rows
    assert len(rows) == len(os.listdir(query)) - len(query_lines)
    assert runner.invoke(app, ["evaluate", str(out)]).exit_code == 0  # the results file reads back


def test_follow_leaves_out_an_empty_file_a_fifo_and_a_looping_link_with_a_line(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    live = tmp_path / "live"
    live.mkdir()
    (live / "img0.png").write_bytes((query / "img0.png").read_bytes())
    (live / "Image091.jpg").write_bytes(b"")
    os.mkfifo(live / "Image092.png")
    (live / "Image093.png").symlink_to("Image093.png")  # a link that loops
    (live / BAD_NAME).write_bytes((query / "img1.png").read_bytes())
    out = tmp_path / "follow.csv"
    result = runner.invoke(app, ["localize", str(live), "--map", str(ref), "--method", "threshold", "--follow",
                                 "--idle", "0.5", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert sorted(result.stderr.strip().splitlines()) == [
        f"skipped {live / 'Image091.jpg'}: empty file (0 bytes)", f"skipped {live / 'Image092.png'}: not a regular file",
        f"skipped {live / 'Image093.png'}: symbolic link loop",
        f"skipped {live}/Image\\xff\\xfe050.png: file name is not valid UTF-8; rename the file to use it"]
    assert runner.invoke(app, ["evaluate", str(out)]).exit_code == 0


def test_follow_of_a_folder_of_sub_folders_says_they_are_not_searched(route: tuple[Path, Path], tmp_path: Path) -> None:
    """A camera's parent folder given to --follow by mistake: a note names its sub-folders, as a
    batch run's error does, where it followed in vain without a line."""
    ref, query = route
    parent = tmp_path / "cameras"
    for camera in ("cam1", "cam0"):
        (parent / camera).mkdir(parents=True)
        (parent / camera / "img0.png").write_bytes((query / "img0.png").read_bytes())
    result = runner.invoke(app, ["localize", str(parent), "--map", str(ref), "--method", "threshold", "--follow",
                                 "--idle", "0.2", "--out", str(tmp_path / "follow.csv")])
    assert result.exit_code == 0, result.output
    assert result.stderr.strip().splitlines() == [
        f"note {parent}: no image files yet; sub-folders are not searched: give the one holding the images (cam0, cam1)"]


# ------------------------------------------------------------------ the Python API: wiloc errors

FLAG = re.compile(r"(?<![\w-])--[a-z]")


def _raised_texts(module: Path) -> list[tuple[int, str]]:
    """(line, text) of every string written inside a ``raise`` statement of ``module``."""
    texts = []
    for node in ast.walk(ast.parse(module.read_text())):
        if isinstance(node, ast.Raise) and node.exc is not None:
            texts += [(c.lineno, c.value) for c in ast.walk(node.exc)
                      if isinstance(c, ast.Constant) and isinstance(c.value, str)]
    return texts


def test_library_errors_name_parameters_not_flags() -> None:
    """Only the command line knows its flags: a library error names the parameter
    (``WilocError(..., parameter=...)``), which the command line shows as its flag."""
    package = Path(__file__).resolve().parents[1] / "wiloc"
    found = [f"{path.relative_to(package)}:{line}: {text!r}" for path in sorted(package.rglob("*.py"))
             if path.relative_to(package).parts[0] != "cli" for line, text in _raised_texts(path) if FLAG.search(text)]
    assert not found, found


def test_a_library_error_names_the_parameter_and_the_command_line_its_flag(route: tuple[Path, Path],
                                                                           cache_dir: Path) -> None:
    from wiloc.description.describing import describe_folder
    from wiloc.descriptors.registry import get_descriptor

    ref, _ = route
    with pytest.raises(ParameterError) as caught:
        describe_folder(ref, get_descriptor("sad"), Cache(cache_dir), jobs=0)
    assert caught.value.parameter == "jobs" and str(caught.value) == "jobs: must be at least 1, got 0"
    ends_in_one_error(runner.invoke(app, ["describe", str(ref), "--jobs", "0"]), 2, "--jobs: must be at least 1, got 0")


@pytest.fixture(scope="module")
def described_map(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Cache]:
    """A reference as :func:`route`'s (the same 30 places, gain and noise) and a cache holding its
    sad and gist descriptors, made once a module: the tests only read them."""
    root = tmp_path_factory.mktemp("described-map")
    ref, cache = write_traversal(root / "ref", places(30), 1.0, 1), Cache(root / "cache")
    for descriptor in ("sad", "gist"):
        Localizer(ref, descriptor=descriptor, method="threshold", cache=cache, jobs=1)
    return ref, cache


@pytest.fixture
def localizers(described_map: tuple[Path, Cache]) -> dict[str, Localizer]:
    """A new threshold localizer per descriptor, none of which has observed a frame yet."""
    ref, cache = described_map
    return {descriptor: Localizer(ref, descriptor=descriptor, method="threshold", cache=cache, jobs=1)
            for descriptor in ("sad", "gist")}


BAD_FRAMES = {
    "empty image": ("sad", np.zeros((0, 0), np.uint8), "observe: an empty image (0 x 0 pixels)"),
    "bool image": ("sad", np.zeros((8, 8), bool), "an image of bool values; give 8- or 16-bit integers or floats in [0, 1]"),
    "float image out of range": ("sad", np.full((40, 60, 3), 2.0), "a float64 image must hold values in [0, 1]"),
    "two channels": ("gist", np.zeros((8, 8, 2), np.uint8), "got shape (8, 8, 2)"),
    "float row to sad": ("sad", np.full(1152, 0.5, np.float32), "a descriptor of float32 values; this map's rows are uint8"),
    "nan row": ("gist", np.full(512, np.nan, np.float32), "the descriptor holds NaN or infinite values"),
    "inf row": ("gist", np.full(512, np.inf, np.float32), "the descriptor holds NaN or infinite values"),
}


@pytest.mark.parametrize("case", BAD_FRAMES)
def test_observe_refuses_what_it_cannot_describe_with_a_wiloc_error(case: str, localizers: dict[str, Localizer]) -> None:
    descriptor, frame, message = BAD_FRAMES[case]
    loc = localizers[descriptor]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy warning leaks either
        with pytest.raises(WilocError, match=re.escape(message)):
            loc.observe(frame)
    assert loc.frames == 0


def test_observe_takes_float_images_in_0_1_as_their_8_bit_values(localizers: dict[str, Localizer],
                                                                 route: tuple[Path, Path]) -> None:
    _, query = route
    image = cv2.cvtColor(cv2.imread(str(query / "img4.png"), cv2.IMREAD_GRAYSCALE), cv2.COLOR_GRAY2BGR)
    for loc in localizers.values():
        as_bytes = loc.describe(image)
        assert np.array_equal(loc.describe(image / 255.0), as_bytes)
        assert np.array_equal(loc.describe(image.astype(np.uint16) * 257), as_bytes)  # 16-bit, as a 16-bit file


def test_a_float_row_against_uint8_rows_is_a_wiloc_error() -> None:
    rows = np.zeros((3, 1152), np.uint8)
    with pytest.raises(ParameterError, match="a: rows of float32 cannot be compared with uint8 reference rows"):
        DifferencesTo(rows, "l1")(np.zeros((1, 1152), np.float32))


@pytest.mark.realdata
@pytest.mark.parametrize("descriptor", ["sad", "gist", "brisk-gist"])
def test_a_file_and_the_array_read_gives_are_the_map_s_descriptor(descriptor: str, data_root: Path,
                                                                  real_data_cache: Path) -> None:
    """``observe(path)``, ``observe(loc.read(path))`` and the cache describe every Gardens Point
    day_left frame alike (so they decide alike)."""
    folder = data_root / "gardens-point-walking" / "day_left"
    loc = Localizer(folder, descriptor=descriptor, method="threshold", cache=Cache(real_data_cache))
    paths = [folder / name for name in loc.map_names]
    assert len(paths) == 200
    for path, cached in zip(paths, loc.describer.entry(folder).data):
        assert np.array_equal(loc.describe(path), cached), path.name
        assert np.array_equal(loc.describe(loc.read(path)), cached), path.name


# ------------------------------------------------------------ results files edited out of range

def _edited(results: Path, column: str, value: str, out: Path) -> Path:
    """``results`` with the first row's ``column`` cell replaced by ``value``."""
    lines = results.read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("frame,"))
    row = lines[first + 1].split(",")
    row[lines[first].split(",").index(column)] = value
    out.write_text("\n".join(lines[:first + 1] + [",".join(row)] + lines[first + 2:]) + "\n")
    return out


@pytest.fixture
def online_results(route: tuple[Path, Path], tmp_path: Path) -> Path:
    ref, query = route
    out = tmp_path / "online.csv"
    assert runner.invoke(app, ["localize", str(query), "--map", str(ref), "--out", str(out), "--jobs", "1"]).exit_code == 0
    return out


@pytest.mark.parametrize("column, value, message", [
    ("confidence", "7.5", "confidence 7.5 is not in [0, 1]"), ("confidence", "-3", "confidence -3 is not in [0, 1]"),
    ("confidence", "inf", "confidence inf is not in [0, 1]"), ("new_place", "1.5", "new_place 1.5 is not in [0, 1]"),
    ("new_place", "-inf", "new_place -inf is not in [0, 1]")])
def test_probabilities_outside_0_1_are_refused(column: str, value: str, message: str, online_results: Path,
                                               tmp_path: Path) -> None:
    edited = _edited(online_results, column, value, tmp_path / "edited.csv")
    line = next(i for i, text in enumerate(edited.read_text().splitlines()) if text.startswith("frame,")) + 2
    ends_in_one_error(runner.invoke(app, ["evaluate", str(edited)]), 1, f"{edited}: line {line}: {message}")


def test_threshold_confidence_may_be_below_0_but_not_above_1(results: Path, tmp_path: Path) -> None:
    assert runner.invoke(app, ["evaluate", str(_edited(results, "confidence", "-3", tmp_path / "low.csv"))]).exit_code == 0
    for value in ("7.5", "-inf"):
        edited = _edited(results, "confidence", value, tmp_path / "edited.csv")
        ends_in_one_error(runner.invoke(app, ["evaluate", str(edited)]), 1,
                          f"confidence {value} is not a finite number at most 1 (as threshold writes it)")


# ------------------------------------------------------------------ ground truth: say where

def _positions_csv(path: Path, n: int = 30) -> Path:
    path.write_text("name,x,y\n" + "".join(f"img{i}.png,{i},0\n" for i in range(n)))
    return path


@pytest.mark.parametrize("args, code, message", [
    (["--gt", "positions:{tmp}/q.csv", "--radius", "2.5"], 2,
     "--gt-map: a run against a map needs the map's positions file too"),
    (["--gt", "positions:{tmp}/q.csv", "--gt-map", "{tmp}/q.csv", "--radius", "-1"], 2,
     "--radius: must be a finite number >= 0 metres, got -1.0"),
    # an infinite radius would make every pair of frames the same place
    (["--gt", "positions:{tmp}/q.csv", "--gt-map", "{tmp}/q.csv", "--radius", "inf"], 2,
     "--radius: must be a finite number >= 0 metres, got inf"),
    (["--gt", "positions:{tmp}/q.csv", "--gt-map", "{tmp}/q.csv", "--radius", "nan"], 2,
     "--radius: must be a finite number >= 0 metres, got nan"),
    (["--gt", "positions:", "--radius", "1"], 2, "--gt: positions ground truth needs a file (positions:FILE)"),
    # checked as given, before the images are read for their names or EXIF (which these have not)
    (["--gt", "exif", "--radius", "-1"], 2, "--radius: must be a finite number >= 0 metres, got -1.0"),
    (["--gt", "utm-names", "--radius", "nan"], 2, "--radius: must be a finite number >= 0 metres, got nan"),
    (["--gt", "matrix:/dev/null"], 1, "/dev/null: not a regular file"),
])
def test_ground_truth_problems_name_the_option_or_file(args: list[str], code: int, message: str, results: Path,
                                                       tmp_path: Path) -> None:
    _positions_csv(tmp_path / "q.csv")
    args = [a.format(tmp=tmp_path) for a in args]
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), *args]), code, message)


@pytest.mark.parametrize("command", ["compare", "evaluate"])
@pytest.mark.parametrize("twice", ["same", "relative"])
def test_compare_refuses_a_results_file_given_twice(twice: str, command: str, results: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """evaluate printed such a run twice under one label, where compare and report refused it."""
    monkeypatch.chdir(results.parent)
    again = str(results) if twice == "same" else results.name
    spelling = "" if twice == "same" else f" (as {results})"
    ends_in_one_error(runner.invoke(app, [command, str(results), again]), 2,
                      f"RESULTS...: {again} is given twice{spelling}; each run counts once")


def test_a_device_or_a_pipe_given_as_results_is_not_called_missing(tmp_path: Path) -> None:
    """/dev/null and a FIFO were "results file does not exist", as --gt's same path is not."""
    fifo = tmp_path / "p.csv"
    os.mkfifo(fifo)
    for path in ("/dev/null", str(fifo)):
        ends_in_one_error(runner.invoke(app, ["evaluate", path]), 1, f"{path}: not a regular file")


@pytest.mark.parametrize("target", ["150", "0", "-5", "nan"])
def test_compare_refuses_a_precision_that_is_no_percentage(target: str, results: Path) -> None:
    ends_in_one_error(runner.invoke(app, ["compare", str(results), "--precision", f"99,{target}"]), 2,
                      f"--precision: {float(target):g} is not a percentage in (0, 100]")


# ------------------------------------------------------------------------------ a full disk

def _disk_full(*args: object) -> None:
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.mark.parametrize(("call", "suffix", "left"), [("fsync", ".h5", "*.h5*"), ("pwrite", ".h5.lock", "*.lock")])
def test_a_full_disk_names_the_cache_file_and_leaves_none(route: tuple[Path, Path], cache_dir: Path,
                                                          monkeypatch: pytest.MonkeyPatch, call: str, suffix: str,
                                                          left: str) -> None:
    # fsync fails while a cache entry is written, pwrite while its lock is taken
    ref, _ = route
    monkeypatch.setattr(os, call, _disk_full)
    result = runner.invoke(app, ["describe", str(ref), "--jobs", "1"])
    ends_in_one_error(result, 1, f"{cache_dir}/descriptors/", f"{suffix}: cannot write the cache (No space left on device)")
    assert not list((cache_dir / "descriptors").glob(left))  # no half-written entry, no lock left


def test_a_full_disk_names_the_followed_results_file(route: tuple[Path, Path], tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    ref, query = route
    out = tmp_path / "follow.csv"
    write = os.write

    def full_for_results(fd: int, data: bytes) -> int:
        if os.readlink(f"/proc/self/fd/{fd}") == str(out):
            _disk_full()
        return write(fd, data)
    monkeypatch.setattr(os, "write", full_for_results)
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold", "--follow",
                                 "--idle", "0.5", "--out", str(out)])
    ends_in_one_error(result, 1, f"{out}: cannot write the results file (No space left on device)")


def test_a_localizer_state_that_cannot_be_written_is_a_wiloc_error(localizers: dict[str, Localizer], tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "replace", _disk_full)
    with pytest.raises(WilocError, match=re.escape(f"{tmp_path / 'state.npz'}: cannot write the localizer state")):
        localizers["sad"].save(tmp_path / "state.npz")
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".state.npz")]


def test_an_out_folder_is_created(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    result = runner.invoke(app, ["localize", str(query), str(ref), "--map", str(ref), "--method", "threshold",
                                 "--out", str(tmp_path / "runs" / "today")])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "runs" / "today").iterdir()) == ["query-sad-threshold.csv",
                                                                              "ref-sad-threshold.csv"]


def test_a_byte_order_mark_is_read_past_in_results_and_ground_truth(results: Path, tmp_path: Path) -> None:
    marked = tmp_path / "marked.csv"
    marked.write_bytes(b"\xef\xbb\xbf" + results.read_bytes())
    pairs = tmp_path / "pairs.csv"
    pairs.write_bytes(b"\xef\xbb\xbfquery,reference\n" + b"".join(b"img%d.png,img%d.png\n" % (i, i) for i in range(30)))
    reports = []
    for path in (results, marked):
        result = runner.invoke(app, ["evaluate", str(path), "--gt", f"pairs:{pairs}", "--json"])
        assert result.exit_code == 0, result.output
        reports.append(json.loads(result.stdout)["runs"][0])
    assert reports[1]["with_true_match"] == 30
    assert {k: v for k, v in reports[0].items() if k != "results"} == {k: v for k, v in reports[1].items() if k != "results"}


def _huge_jpeg(path: Path) -> Path:
    """A small JPEG whose frame header says 65000 x 65000 pixels: over the limit even at the 1/8
    decode a descriptor would use."""
    data = bytearray(cv2.imencode(".jpg", np.full((64, 96), 128, np.uint8))[1].tobytes())
    pos = 2
    while data[pos + 1] not in (0xC0, 0xC1, 0xC2):  # to the start-of-frame segment
        pos += 2 + int.from_bytes(data[pos + 2:pos + 4], "big")
    data[pos + 5:pos + 9] = struct.pack(">HH", 65000, 65000)
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("descriptor", ["sad", "gist"])
def test_a_jpeg_over_the_pixel_limit_is_skipped_even_when_decoded_reduced(descriptor: str, route: tuple[Path, Path]) -> None:
    ref, _ = route
    _huge_jpeg(ref / "img99.jpg")
    result = runner.invoke(app, ["describe", str(ref), "--descriptor", descriptor, "--jobs", "1", "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    [row] = report["results"]
    assert (row["frames"], row["failed"], row["shape"][0]) == (31, 1, 30)
    assert report["warnings"] == [f"skipped: {ref / 'img99.jpg'}: image over OpenCV's size limit (2^30 pixels; "
                               "the environment variable OPENCV_IO_MAX_IMAGE_PIXELS raises it)"]


def test_a_run_whose_images_changed_cannot_be_drawn(route: tuple[Path, Path], results: Path, tmp_path: Path) -> None:
    _, query = route
    image = cv2.imread(str(query / "img3.png"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(query / "img3.png"), 255 - image)
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), "--matrix-plot", str(tmp_path / "m.png")]), 1,
                      f"{results}: its query {query.resolve()} no longer gives the descriptors the run used")
    assert not (tmp_path / "m.png").exists()


def test_a_header_naming_another_folder_of_the_same_names_is_drawn_only_if_it_describes_alike(
        route: tuple[Path, Path], results: Path, tmp_path: Path) -> None:
    ref, _ = route
    twin = tmp_path / "twin"
    twin.mkdir()
    for path in ref.iterdir():
        (twin / path.name).write_bytes(path.read_bytes())
    moved = tmp_path / "moved.csv"
    moved.write_text(results.read_text().replace(f"# map: {ref.resolve()}\n", f"# map: {twin.resolve()}\n"))
    assert runner.invoke(app, ["evaluate", str(moved), "--matrix-plot", str(tmp_path / "same.png")]).exit_code == 0
    image = cv2.imread(str(twin / "img7.png"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(twin / "img7.png"), np.roll(image, 20, axis=1))
    ends_in_one_error(runner.invoke(app, ["evaluate", str(moved), "--matrix-plot", str(tmp_path / "m.png")]), 1,
                      f"its map {twin.resolve()} no longer gives the descriptors the run used")


def test_observe_refuses_a_file_that_cannot_be_a_frame(localizers: dict[str, Localizer], route: tuple[Path, Path],
                                                       tmp_path: Path) -> None:
    _, query = route
    (tmp_path / BAD_NAME).write_bytes((query / "img0.png").read_bytes())
    os.mkfifo(tmp_path / "fifo.png")
    loc = localizers["sad"]
    with pytest.raises(FrameError, match="file name is not valid UTF-8"):
        loc.observe(tmp_path / BAD_NAME)
    with pytest.raises(FrameError, match="fifo.png: not a regular file"):
        loc.observe(tmp_path / "fifo.png")  # refused, not read (a FIFO would block)
    assert loc.frames == 0


def test_observe_refuses_a_frame_cut_short(localizers: dict[str, Localizer], route: tuple[Path, Path]) -> None:
    _, query = route
    _cut_short_frames(query)
    loc = localizers["gist"]  # gist decodes a JPEG reduced: the cut is found all the same
    for name, message in (("img30.jpg", "img30.jpg: truncated JPEG"), ("img31.png", "img31.png: truncated PNG")):
        with pytest.raises(FrameError, match=message):
            loc.observe(query / name)
    assert loc.frames == 0
    loc.observe(query / "img32.jpg")
    assert loc.frames == 1


def test_training_ground_truth_problems_name_the_training_options(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    positions = _positions_csv(tmp_path / "q.csv")
    args = ["localize", str(query), "--map", str(ref), "--method", "trained", "--train-query", str(query),
            "--train-map", str(ref), "--train-gt", f"positions:{positions}", "--out", str(tmp_path / "o.csv")]
    ends_in_one_error(runner.invoke(app, [*args, "--train-radius", "2"]), 2, "--train-gt-map: a run against a map needs")
    ends_in_one_error(runner.invoke(app, [*args, "--train-gt-map", str(positions), "--train-radius", "-2"]), 2,
                      "--train-radius: must be a finite number >= 0 metres, got -2.0")
    assert not (tmp_path / "o.csv").exists()


# Results, ground truth, evaluate and compare

def _twin_map(ref: Path, results: Path, tmp_path: Path) -> Path:
    """``results`` with its ``# map:`` header moved to a copy of ``ref`` whose img7.png differs."""
    twin = tmp_path / "twin"
    twin.mkdir()
    for path in ref.iterdir():
        (twin / path.name).write_bytes(path.read_bytes())
    image = cv2.imread(str(twin / "img7.png"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(twin / "img7.png"), np.roll(image, 20, axis=1))
    moved = tmp_path / "moved.csv"
    moved.write_text(results.read_text().replace(f"# map: {ref.resolve()}\n", f"# map: {twin.resolve()}\n"))
    return moved


@pytest.mark.parametrize("mark", [b"", b"\xef\xbb\xbf"])
def test_compare_refuses_a_copy_of_a_results_file(mark: bytes, results: Path, tmp_path: Path) -> None:
    copy = tmp_path / "copy.csv"
    copy.write_bytes(mark + results.read_bytes())
    ends_in_one_error(runner.invoke(app, ["compare", str(results), str(copy)]), 2,
                      f"RESULTS...: {copy} holds the same run as {results} (identical contents); each run counts once")


@pytest.mark.parametrize("how", ["sorted", "crlf"])
def test_compare_refuses_a_reordered_copy_of_a_results_file(how: str, results: Path, tmp_path: Path) -> None:
    """A results file sorted (by confidence, in a spreadsheet) or saved with CRLF line endings is
    still the run it was: it does not count as a second one."""
    text = results.read_text()
    header = [line for line in text.splitlines() if line.startswith("#")]
    rows = [line for line in text.splitlines() if line and not line.startswith("#")]
    copy = tmp_path / "copy.csv"
    if how == "sorted":
        copy.write_text("\n".join([*header, rows[0], *sorted(rows[1:], key=lambda row: row.split(",")[-1])]) + "\n")
        assert copy.read_text() != text
    else:
        copy.write_bytes(text.replace("\n", "\r\n").encode())
    ends_in_one_error(runner.invoke(app, ["compare", str(results), str(copy)]), 2,
                      f"RESULTS...: {copy} holds the same run as {results} (the same lines, in another order or with "
                      "other line endings); each run counts once")


def test_compare_refuses_a_run_in_memory_given_twice(route: tuple[Path, Path]) -> None:
    """A run held in memory (no results file), given twice, as it is or once inside its localize
    run, counts once: refused, as a file given twice is; two runs of other methods are two."""
    from wiloc import api

    ref, query = route
    run = api.localize(query, reference=ref, method="threshold", jobs=1)
    truth = api.TruthSource(kind="aligned", tolerance=2)
    for twice in ([run, run], [run, run.results], [run.results, run.results]):
        with pytest.raises(ParameterError, match=r"^runs: the run of threshold on .*query in memory is given twice; "
                                                 r"each run counts once$"):
            api.compare(twice, truth)
    other = api.localize(query, reference=ref, method="online", jobs=1)
    assert len(api.compare([run, other], truth).table1) == 2


def test_compare_refuses_a_written_run_given_twice(route: tuple[Path, Path], tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A localize run written to a file (out=), given twice as the run, or as the run and its
    file by any path, was counted twice in the tables: its two entries carried one Path object,
    which the check for a file given twice took for one entry. Its results, given beside it, are
    the same run too."""
    from wiloc import api

    ref, query = route
    monkeypatch.chdir(tmp_path)
    run = api.localize(query, reference=ref, method="threshold", out=tmp_path / "dup.csv", jobs=1)
    truth = api.TruthSource(kind="aligned", tolerance=2)
    for twice in ([run, run], [run, run.path], [run.path, run], [run, "dup.csv"], [run.path, run.path]):
        with pytest.raises(ParameterError, match=r"^runs: .*dup\.csv is given twice( \(as .*dup\.csv\))?; "
                                                 r"each run counts once$"):
            api.compare(twice, truth)
    with pytest.raises(ParameterError, match=r"^runs: the run of threshold on .*query in memory is given twice; "
                                             r"each run counts once$"):
        api.compare([run, run.results], truth)
    other = api.localize(query, reference=ref, method="online", out=tmp_path / "other.csv", jobs=1)
    assert len(api.compare([run, other], truth).table1) == 2


@pytest.mark.parametrize("targets", ["", ",,"])
def test_compare_refuses_no_target_precision(targets: str, results: Path) -> None:
    ends_in_one_error(runner.invoke(app, ["compare", str(results), "--precision", targets]), 2,
                      "--precision: no target precision")


def _bad_truth_files(folder: Path) -> None:
    for name in ("empty.npy", "empty.mat", "empty.csv"):
        (folder / name).write_bytes(b"")
    (folder / "text.npy").write_text("img0.png,img0.png\n")
    (folder / "garbage.mat").write_bytes(b"MATLAB 5.0 MAT-file, cut short")
    (folder / "ragged.csv").write_text("1,0,0\n0,1,0\n\n0,1\n")
    (folder / "header.csv").write_text("query,reference\n")


@pytest.mark.parametrize("gt, message", [
    ("matrix:{tmp}/empty.npy", "{tmp}/empty.npy: the file is empty (0 bytes)"),
    ("matrix:{tmp}/empty.mat", "{tmp}/empty.mat: the file is empty (0 bytes)"),
    ("matrix:{tmp}/empty.csv", "{tmp}/empty.csv: the file is empty (0 bytes)"),
    ("pairs:{tmp}/empty.csv", "{tmp}/empty.csv: the file is empty (0 bytes)"),
    ("vprbench:{tmp}/empty.npy", "{tmp}/empty.npy: the file is empty (0 bytes)"),
    ("matrix:{tmp}/text.npy", "{tmp}/text.npy: cannot read matrix (no NumPy array header: not an .npy array"),
    ("matrix:{tmp}/garbage.mat", "{tmp}/garbage.mat: cannot read matrix"),
    ("matrix:{tmp}/ragged.csv", "{tmp}/ragged.csv: cannot read matrix (line 4 has 2 values where line 1 has 3)"),
    ("pairs:{tmp}/header.csv", "{tmp}/header.csv: holds no pairs, only its header line: list each true match"),
])
def test_empty_and_unreadable_ground_truth_files_are_one_line(gt: str, message: str, results: Path,
                                                              tmp_path: Path) -> None:
    _bad_truth_files(tmp_path)
    result = runner.invoke(app, ["evaluate", str(results), "--gt", gt.format(tmp=tmp_path)])
    ends_in_one_error(result, 1, message.format(tmp=tmp_path))
    assert "allow_pickle" not in result.stderr and "unsafely" not in result.stderr and "usecols" not in result.stderr


def test_a_matrix_csv_with_a_byte_order_mark_is_read(results: Path, tmp_path: Path) -> None:
    text = "".join(",".join("1" if i == j else "0" for j in range(30)) + "\n" for i in range(30)).encode()
    reports = []
    for name, mark in (("plain.csv", b""), ("marked.csv", b"\xef\xbb\xbf")):
        (tmp_path / name).write_bytes(mark + text)
        result = runner.invoke(app, ["evaluate", str(results), "--gt", f"matrix:{tmp_path / name}", "--json"])
        assert result.exit_code == 0, result.output
        reports.append({k: v for k, v in json.loads(result.stdout)["runs"][0].items() if k != "ground_truth"})
    assert reports[0]["with_true_match"] == reports[1]["with_true_match"] == 30
    assert reports[0] == reports[1]


@pytest.mark.parametrize("option", ["--csv", "--pr-plot"])
def test_an_output_that_is_no_regular_file_is_refused_not_replaced(option: str, results: Path, tmp_path: Path) -> None:
    fifo = tmp_path / "out.png"
    os.mkfifo(fifo)
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), option, str(fifo)]), 2,
                      f"{option}: {fifo}: it is not a regular file (a device, a pipe or a folder)")
    assert fifo.is_fifo()


def test_an_output_that_is_the_commands_own_stdout_is_refused(results: Path, tmp_path: Path) -> None:
    """`--csv /dev/stdout > out.txt`: the link leads to the file the command prints to, which
    replacing would lose (and, followed blindly, would replace /dev/stdout itself)."""
    printed = tmp_path / "printed.txt"
    with printed.open("w") as stdout:
        result = subprocess.run([str(_console_script()), "evaluate", str(results), "--csv", "/dev/stdout"],
                                stdout=stdout, stderr=subprocess.PIPE, text=True, timeout=120, check=False)
    assert result.returncode == 2
    assert result.stderr.strip() == ("error: --csv: /dev/stdout: it is this command's standard output, which writing "
                                     "would replace (give a file of its own)")
    assert Path("/dev/stdout").is_symlink() and printed.read_text() == ""


def test_an_output_through_a_symbolic_link_replaces_its_target_and_keeps_the_link(results: Path,
                                                                                   tmp_path: Path) -> None:
    target = tmp_path / "run-2.csv"
    target.write_text("old\n")
    latest = tmp_path / "latest.csv"
    latest.symlink_to(target.name)
    assert runner.invoke(app, ["evaluate", str(results), "--csv", str(latest)]).exit_code == 0
    assert latest.is_symlink() and os.readlink(latest) == target.name
    assert target.read_text().startswith("run,results,method")


def test_a_dash_is_no_output_file(results: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), "--csv", "-"]), 2,
                      "--csv: -: wiloc writes files here, not standard output")
    assert list(here.iterdir()) == []


def test_an_output_name_as_long_as_the_file_system_takes_is_written(results: Path, tmp_path: Path) -> None:
    """A name of 255 bytes, the longest most file systems take (its temporary file's name would
    be longer: it is shortened, with a digest of the name)."""
    (tmp_path / "figures").mkdir()
    out = tmp_path / "figures" / ("q" * 251 + ".png")
    result = runner.invoke(app, ["evaluate", str(results), "--pr-plot", str(out)])
    assert result.exit_code == 0, result.output
    assert [p.name for p in out.parent.iterdir()] == [out.name] and out.stat().st_size > 0


@pytest.mark.parametrize("command, option, suffix", [
    ("evaluate", "--pr-plot", ".png"), ("evaluate", "--csv", ".csv"), ("report", "-o", ".html"),
    ("localize", "--out", ".csv"), ("demo", "--out", "")])
def test_an_output_name_longer_than_the_file_system_takes_is_one_line(
        results: Path, route: tuple[Path, Path], tmp_path: Path, command: str, option: str, suffix: str) -> None:
    """A name over 255 bytes ended in the OSError's traceback (File name too long) as the options
    were checked; so did a --csv name that is fine but whose curves file beside it is not."""
    ref, query = route
    inputs = {"localize": [str(query), "--map", str(ref), "--method", "threshold"],
              "demo": []}.get(command, [str(results)])
    for name in ("q" * 300 + suffix, "q" * (255 - len(suffix)) + suffix):
        if option != "--csv" and len(name) == 255:
            continue  # a name that long is fine for these (test above)
        out = tmp_path / name
        result = runner.invoke(app, [command, *inputs, option, str(out)])
        too_long = out if len(name) > 255 else out.with_name(out.stem + "-curves.csv")
        ends_in_one_error(result, 2, f"{too_long}", "no file can have this name")
    if command == "localize":  # a folder named with a trailing /
        ends_in_one_error(runner.invoke(app, [command, *inputs, option, f"{tmp_path / ('q' * 300)}/"]), 2,
                          "no file can have this name")
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith("qq")] == []


def test_the_library_refuses_to_replace_what_is_no_regular_file(localizers: dict[str, Localizer],
                                                                tmp_path: Path) -> None:
    fifo = tmp_path / "state.npz"
    os.mkfifo(fifo)
    with pytest.raises(WilocError, match=re.escape(f"{fifo}: cannot write the localizer state: it is not a regular")):
        localizers["sad"].save(fifo)
    assert fifo.is_fifo()


def test_example_pairs_refuse_another_folder_of_the_same_names(route: tuple[Path, Path], results: Path,
                                                              tmp_path: Path) -> None:
    ref, _ = route
    moved = _twin_map(ref, results, tmp_path)
    ends_in_one_error(runner.invoke(app, ["evaluate", str(moved), "--pairs-plot", str(tmp_path / "p.png")]), 1,
                      f"{moved}: its map {(tmp_path / 'twin').resolve()} no longer gives the descriptors the run used")
    assert not (tmp_path / "p.png").exists()


def test_the_report_shows_no_images_of_another_folder_of_the_same_names(route: tuple[Path, Path], results: Path,
                                                                       tmp_path: Path) -> None:
    ref, _ = route
    moved = _twin_map(ref, results, tmp_path)
    for run, images in ((results, True), (moved, False)):
        result = runner.invoke(app, ["report", str(run), "-o", str(tmp_path / "r.html"), "--json"])
        assert result.exit_code == 0, result.output
        report = json.loads(result.stdout)
        assert (report["results"][0]["images"] > 0) == images
        assert any(f"no images in the frame browser, its map {(tmp_path / 'twin').resolve()}" in line
                   for line in report["warnings"]) != images


def test_figures_of_a_run_that_recorded_no_digest_say_it_is_unchecked(route: tuple[Path, Path], results: Path,
                                                                      tmp_path: Path) -> None:
    ref, query = route
    older = tmp_path / "older.csv"
    older.write_text("".join(line for line in results.read_text().splitlines(keepends=True)
                             if not line.startswith(("# query_digest:", "# map_digest:"))))
    for run, lines in ((results, []), (older, [f"warning: {older}: the run recorded no digest of its images, so figures "
                                               f"show {query.resolve()} and {ref.resolve()} as they are now, unchecked"])):
        result = runner.invoke(app, ["evaluate", str(run), "--matrix-plot", str(tmp_path / "m.png"), "--json"])
        assert result.exit_code == 0, result.output
        assert [w for w in json.loads(result.stdout)["warnings"] if "digest" in w] == lines


def test_a_ground_truth_matrix_of_differences_is_refused(results: Path, tmp_path: Path) -> None:
    mask = np.eye(30)
    np.save(tmp_path / "mask.npy", mask)
    assert runner.invoke(app, ["evaluate", str(results), "--gt", f"matrix:{tmp_path / 'mask.npy'}"]).exit_code == 0
    distances = np.abs(np.subtract.outer(np.arange(30.0), np.arange(30.0))) / 4
    np.save(tmp_path / "distances.npy", distances)
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), "--gt", f"matrix:{tmp_path / 'distances.npy'}"]), 1,
                      f"{tmp_path / 'distances.npy'}: matrix holds 0.25 at row 1, column 2: ground truth is a "
                      "same-place mask of 0 and 1")


def test_a_match_without_a_confidence_or_a_confidence_without_a_match_is_refused(online_results: Path,
                                                                                 tmp_path: Path) -> None:
    line = next(i for i, text in enumerate(online_results.read_text().splitlines()) if text.startswith("frame,")) + 2
    no_confidence = _edited(online_results, "confidence", "", tmp_path / "no-confidence.csv")
    ends_in_one_error(runner.invoke(app, ["evaluate", str(no_confidence)]), 1,
                      f"{no_confidence}: line {line}: match 'img0.png' has no confidence (a run writes both or neither)")
    no_match = _edited(_edited(online_results, "match", "", tmp_path / "a.csv"), "ranking", "", tmp_path / "no-match.csv")
    ends_in_one_error(runner.invoke(app, ["evaluate", str(no_match)]), 1, f"{no_match}: line {line}: confidence ",
                      "without a match (a run writes both or neither)")


@pytest.mark.parametrize("name", ["notes.txt", "frames.pkl", "README"])
def test_a_file_that_is_no_traversal_says_so_not_that_it_needs_a_metric(name: str, route: tuple[Path, Path],
                                                                        tmp_path: Path) -> None:
    _, query = route
    (tmp_path / name).write_text("not frames\n")
    kind = f"a {Path(name).suffix} file" if Path(name).suffix else "a file without a suffix"
    ends_in_one_error(runner.invoke(app, ["localize", str(query), "--map", str(tmp_path / name), "--out",
                                          str(tmp_path / "o.csv")]), 1,
                      f"{tmp_path / name}: {kind} is not a traversal: give a folder of images, a video or a "
                      "descriptor matrix file (.npy, .npz, .csv, .h5)")


def test_a_refused_figure_leaves_no_other_output_behind(route: tuple[Path, Path], results: Path,
                                                        tmp_path: Path) -> None:
    ref, _ = route
    moved = _twin_map(ref, results, tmp_path)
    outputs = ["--pr-plot", str(tmp_path / "pr.png"), "--calibration-plot", str(tmp_path / "c.png"),
               "--csv", str(tmp_path / "m.csv")]
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), str(moved), *outputs,
                                          "--pairs-plot", str(tmp_path / "p.png")]), 1, "no longer gives the descriptors")
    ends_in_one_error(runner.invoke(app, ["compare", str(results), "--threshold-plot", str(tmp_path / "t.png"),
                                          "--model-plot", str(tmp_path / "model.png")]), 2, "none of the results")
    assert sorted(p.name for p in tmp_path.glob("*.png")) == [] and not (tmp_path / "m.csv").exists()


def test_a_followed_results_file_cut_short_in_its_last_row_is_refused(results: Path, tmp_path: Path) -> None:
    lines = [line for line in results.read_text().splitlines(keepends=True) if not line.startswith("# frames:")]
    first = next(i for i, line in enumerate(lines) if not line.startswith("# "))
    followed = tmp_path / "followed.csv"
    followed.write_text("".join(lines[:first] + ["# follow: True\n"] + lines[first:]))
    assert runner.invoke(app, ["evaluate", str(followed)]).exit_code == 0
    torn = tmp_path / "torn.csv"
    torn.write_bytes(followed.read_bytes()[:-4])
    ends_in_one_error(runner.invoke(app, ["evaluate", str(torn)]), 1,
                      f"{torn}: its last row is cut short (no line end)")


def test_a_batch_results_file_cut_within_its_last_value_is_refused(results: Path, tmp_path: Path) -> None:
    """Only a followed file's torn last row was refused: a batch file cut 4 bytes short (a copy that
    stopped) was read with its last ranking or score cut, a node 101 read as 10."""
    torn = tmp_path / "torn.csv"
    torn.write_bytes(results.read_bytes()[:-4])
    ends_in_one_error(runner.invoke(app, ["evaluate", str(torn)]), 1,
                      f"{torn}: its last row is cut short (no line end): the file was cut")


def test_a_map_frame_named_twice_in_the_header_is_refused(results: Path, tmp_path: Path) -> None:
    edited = tmp_path / "twice.csv"
    edited.write_text(results.read_text().replace('"img1.png"', '"img0.png"', 1))
    line = _header_line(edited, "reference_frames")
    ends_in_one_error(runner.invoke(app, ["evaluate", str(edited)]), 1,
                      f"{edited}: line {line}: header 'reference_frames' names 'img0.png' twice")


def _header_line(path: Path, key: str) -> int:
    """The line number of a results file's header line ``# key: ...``."""
    return next(n for n, text in enumerate(path.read_text().splitlines(), 1) if text.startswith(f"# {key}: "))


def test_a_ground_truth_path_is_read_as_given_but_for_query(route: tuple[Path, Path], results: Path,
                                                            tmp_path: Path) -> None:
    ref, query = route
    braces = _positions_csv(tmp_path / "q{1}.csv")
    result = runner.invoke(app, ["evaluate", str(results), "--gt", f"positions:{braces}", "--gt-map", str(braces),
                                 "--radius", "0.5", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["runs"][0]["with_true_match"] == 30
    template = str(tmp_path / "{query}-positions.csv")
    missing = str(tmp_path / f"{query.name}-positions.csv")
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), "--gt", f"pairs:{template}"]), 1,
                      f"--gt: {missing} ({template} for query {query.name}): file does not exist")
    ends_in_one_error(runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "trained",
                                          "--train-query", str(query), "--train-map", str(ref),
                                          "--train-gt", f"pairs:{template}", "--out", str(tmp_path / "o.csv")]), 1,
                      f"--train-gt: {missing} ({template} for query {query.name}): file does not exist")


# Frames, folders and the Python API

def test_a_folder_whose_path_is_not_utf8_is_one_line_and_writes_nothing(route: tuple[Path, Path],
                                                                       tmp_path: Path) -> None:
    """The cache and results files record folders by their path as UTF-8 text: a folder whose
    name holds other bytes is refused, shown with those bytes escaped, as map, query or followed."""
    ref, query = route
    bad = tmp_path / os.fsdecode(b"r\xffef")
    bad.mkdir()
    for path in ref.iterdir():
        (bad / path.name).write_bytes(path.read_bytes())
    shown = f"{tmp_path}/r\\xffef"
    out = tmp_path / "run.csv"
    ends_in_one_error(runner.invoke(app, ["describe", str(bad)]), 1, f"{shown}: path is not valid UTF-8")
    for args in ([str(query), "--map", str(bad)], [str(bad), "--map", str(ref)], [str(bad)],
                 [str(bad), "--map", str(ref), "--follow", "--idle", "0.5"]):
        ends_in_one_error(runner.invoke(app, ["localize", *args, "--method", "threshold", "--out", str(out)]), 1,
                          f"{shown}: path is not valid UTF-8")
        assert not out.exists()
    ends_in_one_error(runner.invoke(app, ["describe", str(bad / "missing")]), 1, f"{shown}/missing: folder does not exist")


def test_an_image_far_longer_than_wide_is_left_out_with_a_line(route: tuple[Path, Path],
                                                               localizers: dict[str, Localizer]) -> None:
    """gist covers a 256 x 256 square and crops it: a strip of 2 x 600 pixels would be scaled to
    76,800 x 256 (a 1 x 100000 one to 26 GB), so an image with one side over 256 times the other
    is no frame, in a folder as through ``observe``."""
    ref, _ = route
    assert cv2.imwrite(str(ref / "img99.png"), np.full((2, 600), 90, np.uint8))
    result = runner.invoke(app, ["describe", str(ref), "--descriptor", "gist", "--jobs", "1", "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    [row] = report["results"]
    assert (row["frames"], row["failed"], row["shape"]) == (31, 1, [30, 512])
    assert report["warnings"] == [f"skipped: {ref / 'img99.png'}: image of 600 x 2 pixels: one side is over 256 "
                                  "times the other"]
    for loc in localizers.values():
        with pytest.raises(FrameError, match="observe: image of 1 x 300 pixels: one side is over 256 times"):
            loc.observe(np.zeros((300, 1), np.uint8))
        assert loc.observe(np.zeros((1, 256), np.uint8)).frame == "000000"  # 256 times is still a frame


def test_a_float64_row_beyond_float32_is_refused_not_made_infinite(localizers: dict[str, Localizer]) -> None:
    loc = localizers["gist"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's overflow warning does not leak either
        with pytest.raises(WilocError, match="observe: the descriptor holds values beyond the range of this map's "
                                             "float32 rows"):
            loc.observe(np.full(512, 1e39))
    assert loc.frames == 0
    assert loc.observe(np.full(512, 1e15)).frame == "000000"  # large, within its differences' float32: a descriptor


def test_a_video_or_demo_folder_whose_path_is_not_utf8_is_one_line_not_a_crash(tmp_path: Path,
                                                                                cache_dir: Path) -> None:
    """OpenCV crashes (a segmentation fault) opening or writing a path that is not UTF-8: such a
    path is refused before OpenCV sees it. In a subprocess, so that a crash fails only this test."""
    plain = tmp_path / "drive.avi"
    writer = cv2.VideoWriter(str(plain), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for k in range(5):
        writer.write(np.full((48, 64, 3), 40 * k, np.uint8))
    writer.release()
    video = os.fsencode(tmp_path) + b"/drive\xff.avi"
    os.rename(plain, video)
    demo = os.fsencode(tmp_path) + b"/demo\xff"
    for args, shown in ((["describe", video], f"{tmp_path}/drive\\xff.avi"), (["demo", "--out", demo], f"{tmp_path}/demo\\xff")):
        result = subprocess.run([_console_script(), *args], capture_output=True, timeout=120, check=False)
        stderr = result.stderr.decode()
        assert result.returncode == 1 and stderr.count("\n") == 1, (result.returncode, stderr)
        assert stderr.startswith(f"error: {shown}") and "path is not valid UTF-8" in stderr
    assert not os.path.exists(demo)


def test_follow_names_a_file_still_being_written_when_the_run_ends(route: tuple[Path, Path], tmp_path: Path,
                                                                   localizers: dict[str, Localizer]) -> None:
    """A file that grows at every look (after it was caught once, empty) is never handed out
    again; the run ends all the same, and names it as left out, not passed over in silence."""
    from wiloc.localization.follow import FolderWatch, Skipped, follow

    _, query = route
    (tmp_path / "img0.png").write_bytes((query / "img0.png").read_bytes())
    growing = tmp_path / "Image091.jpg"
    growing.write_bytes(b"")
    now = [0.0]

    def sleep(seconds: float) -> None:
        now[0] += seconds
        assert now[0] < 60, "the run never ends"
        with growing.open("ab") as out:
            out.write(b"\xff")

    events = list(follow(localizers["sad"], FolderWatch(tmp_path), idle=1.0, poll=0.25, clock=lambda: now[0],
                         sleep=sleep))
    assert [e.frame for e in events if not isinstance(e, Skipped)] == ["img0.png"]
    assert [str(e) for e in events if isinstance(e, Skipped)] == [
        f"{growing}: still being written when the run ended (not decided; a run resuming this one decides it)"]


def test_observe_takes_a_path_given_as_bytes(localizers: dict[str, Localizer], route: tuple[Path, Path],
                                             tmp_path: Path) -> None:
    """``os.fsencode`` gives a path as bytes, the one spelling of a name that is not UTF-8: it
    is a file, described as its text path is (not an array of one byte string)."""
    _, query = route
    loc = localizers["sad"]
    assert np.array_equal(loc.describe(os.fsencode(query / "img3.png")), loc.describe(query / "img3.png"))
    assert loc.observe(os.fsencode(query / "img3.png")).frame == "img3.png"
    bad = os.fsencode(tmp_path) + b"/Image\xff.png"
    Path(os.fsdecode(bad)).write_bytes((query / "img3.png").read_bytes())
    with pytest.raises(FrameError, match=re.escape(f"{tmp_path}/Image\\xff.png: file name is not valid UTF-8")):
        loc.observe(bad)
    assert loc.frames == 1


@pytest.mark.parametrize(("args", "missing", "kind"), [
    (["localize", "{tmp}/queries.h5", "--map", "{ref}"], "queries.h5", "file"),
    (["localize", "{ref}", "--map", "{tmp}/database.npz"], "database.npz", "file"),
    (["localize", "{tmp}/q.npy", "--map", "{tmp}/m.npy"], "q.npy", "file"),
    (["localize", "{tmp}/q.npy", "--map", "{tmp}/m.npy", "--metric", "l1", "--names", "{tmp}/q.txt"], "q.npy", "file"),
    (["describe", "{tmp}/descriptors.H5"], "descriptors.H5", "file"),
    (["describe", "{tmp}/frame.jpg"], "frame.jpg", "file"),
    (["vocabulary", "{tmp}/route.mp4"], "route.mp4", "file"),
    (["vocabulary", "{tmp}/run.bag"], "run.bag", "file"),
    (["describe", "{tmp}/day_left.v2"], "day_left.v2", "folder"),  # a dot in a folder's name: a folder still
    (["localize", "{tmp}/day_left", "--map", "{ref}"], "day_left", "folder"),
])
def test_a_missing_file_given_as_a_traversal_is_said_to_be_a_file(args: list[str], missing: str, kind: str,
                                                                  route: tuple[Path, Path], tmp_path: Path) -> None:
    """A traversal path that does not exist is a missing file when its suffix names a file wiloc reads
    (a descriptor matrix, an image, a video, a ROS bag), else a missing folder."""
    ref, _ = route
    given = [arg.format(tmp=tmp_path, ref=ref) for arg in args]
    ends_in_one_error(runner.invoke(app, given), 1, f"error: {tmp_path / missing}: {kind} does not exist")


@pytest.mark.parametrize("query", ["missing", "img0.png"])
def test_follow_of_no_folder_is_one_line_and_writes_no_results_file(query: str, route: tuple[Path, Path],
                                                                    tmp_path: Path) -> None:
    ref, _ = route
    given = ref / query
    out = tmp_path / "follow.csv"
    result = runner.invoke(app, ["localize", str(given), "--map", str(ref), "--method", "threshold", "--follow",
                                 "--idle", "0.5", "--out", str(out)])
    ends_in_one_error(result, 1, f"{given}: {'folder does not exist' if query == 'missing' else 'not a folder'}")
    assert not out.exists()  # a later run on the right folder starts anew, not "other settings"


@pytest.mark.parametrize("content", ["empty", "npy", "png", "cut"])
def test_loading_a_file_that_is_no_saved_state_is_a_wiloc_error(content: str, localizers: dict[str, Localizer],
                                                                route: tuple[Path, Path], tmp_path: Path) -> None:
    """An empty file ended in EOFError, an .npy array in TypeError, an image was said to hold
    Python objects: each is one WilocError naming the file."""
    _, query = route
    path = tmp_path / "state.npz"
    if content == "npy":
        with path.open("wb") as out:
            np.save(out, np.zeros(3))
    elif content == "png":
        path.write_bytes((query / "img0.png").read_bytes())
    elif content == "cut":
        loc = localizers["sad"]
        loc.observe(query / "img0.png")
        path.write_bytes(loc.save(tmp_path / "whole.npz").read_bytes()[:300])
    else:
        path.write_bytes(b"")
    problem = ("damaged or truncated: it starts as an .npz file but cannot be read whole" if content == "cut"
               else "not a saved localizer state (not an .npz file)")
    with pytest.raises(WilocError, match=re.escape(f"{path}: {problem}")):
        Localizer.load(path)


def test_describe_of_one_folder_not_in_a_list_describes_that_folder(route: tuple[Path, Path], cache_dir: Path) -> None:
    """``api.describe("ref/")`` took the name's characters for folders ("/: no image files");
    a Path alone was a TypeError. One folder given alone is described as a list of it."""
    from wiloc import api

    ref, _ = route
    [listed] = api.describe([ref], cache=Cache(cache_dir), jobs=1)
    for alone in (str(ref), ref):
        [report] = api.describe(alone, cache=Cache(cache_dir), jobs=1)
        assert report.shape == listed.shape == (30, 1152) and report.folder == listed.folder


def test_vocabulary_of_one_folder_given_alone_is_that_folder(tmp_path: Path) -> None:
    """``api.vocabulary("folder")``, like ``api.describe``, takes one folder given alone as that
    folder, not as the characters of its name."""
    from wiloc import api

    folder = tmp_path / "fr"
    folder.mkdir()
    with pytest.raises(WilocError) as one:
        api.vocabulary(str(folder), cache=Cache(tmp_path / "cache"))
    with pytest.raises(WilocError) as listed:
        api.vocabulary([folder], cache=Cache(tmp_path / "cache"))
    assert str(one.value) == str(listed.value) and str(folder) in str(one.value)


@pytest.mark.parametrize("empty", ["", b""])
def test_observe_names_an_empty_path_as_empty(empty: str | bytes, localizers: dict[str, Localizer]) -> None:
    """An empty path is not the current folder (what ``Path("")`` would make of it)."""
    with pytest.raises(FrameError, match="the frame's path is empty"):
        localizers["sad"].observe(empty)


@pytest.mark.parametrize("suffix", [".txt", ".csv"])
def test_a_names_file_with_a_byte_order_mark_gives_the_names_without_it(suffix: str, tmp_path: Path) -> None:
    """Editors on Windows start UTF-8 text with a byte-order mark; results files and ground truth
    read it as such, and so do frame-name files."""
    from wiloc.descriptors.external import read_names

    path = tmp_path / f"names{suffix}"
    path.write_bytes("\ufeffname\nimg0.png\nimg1.png\n".encode())
    assert read_names(path) == ["img0.png", "img1.png"]


def test_sequence_mode_refuses_a_map_positions_file_other_than_the_query_s(tmp_path: Path) -> None:
    """In sequence mode the traversal is its own map: another map positions file would place the
    same frames twice, differently."""
    from wiloc.evaluation.truth_source import TruthSource

    names = [f"img{i}.png" for i in range(30)]
    own, other = _positions_csv(tmp_path / "q.csv"), _positions_csv(tmp_path / "r.csv")
    truth = TruthSource(kind="positions", path=str(own), ref_path=str(own), radius=10.0)
    assert truth.load(names, names, str(tmp_path), sequence=True, exclude_recent=2).matrix.nnz > 0
    with pytest.raises(ParameterError, match="sequence mode is its own map") as refused:
        TruthSource(kind="positions", path=str(own), ref_path=str(other), radius=2.0).load(
            names, names, str(tmp_path), sequence=True, exclude_recent=2)
    assert refused.value.parameter == "ref_path"


def test_vocabulary_of_one_folder_given_twice_is_refused(route: tuple[Path, Path], cache_dir: Path) -> None:
    """A folder typed twice (``ref ref/``) would count its images twice in the clustering: refused
    before any work, naming it."""
    ref, _ = route
    ends_in_one_error(runner.invoke(app, ["vocabulary", str(ref), f"{ref}/", "--words", "2"]), 2,
                      f"FOLDER...: {ref} is given twice")
    assert not list(cache_dir.glob("vocabularies/*"))


def test_demo_out_under_a_file_is_a_usage_error_before_any_work(tmp_path: Path, cache_dir: Path) -> None:
    """`demo --out` names a folder: a file there (or above it) is refused naming --out, where the
    demo drew its route first and failed inside it ('route/reference: Not a directory', exit 1)."""
    taken = tmp_path / "notes.txt"
    taken.write_text("mine")
    for out in (taken, taken / "demo"):
        ends_in_one_error(runner.invoke(app, ["demo", "--out", str(out)]), 2, f"--out: {taken} is a file, not a folder")
    assert taken.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_a_message_that_spans_lines_is_printed_as_one(results: Path, tmp_path: Path) -> None:
    """A problem's line breaks become spaces (pandas' message for a CSV it could not tokenize
    ended in one: its ')' was printed on a line of its own). A results file given as ground truth
    names the line whose cells do not fit its first. A name holding a line break is written as \\n."""
    result = runner.invoke(app, ["evaluate", str(results), "--gt", str(results)])
    ends_in_one_error(result, 1, f"{results}: line ", "cell(s), where the header (line 1) names 1 columns")
    assert str(WilocError(tmp_path / "a\nb.csv", "line one\n  line two")) == f"{tmp_path}/a\\nb.csv: line one line two"


def test_ground_truth_files_may_be_given_as_paths(tmp_path: Path) -> None:
    """``TruthSource`` takes path-like files as the rest of the API does (a ``Path`` ended in a
    TypeError), ``{query}`` in them too."""
    from wiloc.evaluation.truth_source import TruthSource

    names = [f"img{i}.png" for i in range(30)]
    own = _positions_csv(tmp_path / "q.csv")
    as_text = TruthSource(kind="positions", path=str(own), ref_path=str(own), radius=10.0)
    as_path = TruthSource(kind="positions", path=own, ref_path=tmp_path / "{query}.csv", radius=10.0)
    expected = as_text.load(names, names, str(tmp_path / "q"), sequence=True, exclude_recent=2).matrix
    got = as_path.load(names, names, str(tmp_path / "q"), sequence=True, exclude_recent=2).matrix
    assert expected.nnz > 0 and (expected != got).nnz == 0
    with pytest.raises(WilocError, match="file does not exist"):
        TruthSource(kind="pairs", path=tmp_path / "gone.csv").load(names, names, str(tmp_path), False, 10)


def test_a_tolerance_wider_than_the_map_is_the_whole_map(results: Path) -> None:
    """--tolerance beyond int64 (a typo of many digits) counts every map frame as a true match, as
    one of the map's length does: it ended in numpy's OverflowError, with a traceback."""
    def metrics(tolerance: int) -> dict[str, object]:
        result = runner.invoke(app, ["evaluate", str(results), "--tolerance", str(tolerance), "--json"])
        assert result.exit_code == 0, result.output
        return {k: v for k, v in json.loads(result.stdout)["runs"][0].items() if k != "ground_truth"}

    assert metrics(10 ** 23) == metrics(30)


def test_a_pairs_tolerance_wider_than_the_map_is_the_whole_map(tmp_path: Path) -> None:
    """A pairs file's tolerance of 1e30 marks the whole map, as one of the map's length does: cast
    to int64 it wrapped to a negative band, so that row silently had no true match at all."""
    from wiloc.evaluation.truth_source import TruthSource

    names = [f"img{i}.png" for i in range(30)]
    truths = {}
    for tolerance in ("1e30", "30"):
        path = tmp_path / f"pairs-{tolerance}.csv"
        path.write_text(f"query,reference,tolerance\nimg3.png,img3.png,{tolerance}\nimg4.png,img4.png,1\n")
        truths[tolerance] = TruthSource(kind="pairs", path=path).load(names, names, str(tmp_path), False, 10).matrix
    assert truths["30"][[3]].nnz == 30 and (truths["1e30"] != truths["30"]).nnz == 0


def test_a_model_header_whose_counts_do_not_fit_its_bins_is_refused(online_results: Path, tmp_path: Path) -> None:
    """A results file's model with one bin edge deleted by hand is no histogram model: compare
    --model-plot ended in matplotlib's size mismatch, with a traceback."""
    run = online_results
    run.write_text(re.sub(r'("edges": \[)[^,]+, ', r"\1", run.read_text(), count=1))
    figure = tmp_path / "fig1.png"
    ends_in_one_error(runner.invoke(app, ["compare", str(run), "--model-plot", str(figure)]), 1,
                      f"{run}: line {_header_line(run, 'model')}: header 'model' is not a histogram model "
                      "(b must hold a count >= 0 for each of the 99 bins)")
    assert not figure.exists()


@pytest.mark.parametrize("given", ["particles=5", [("crop", "none")]])
def test_parameters_given_as_no_mapping_are_a_parameter_error(given: object, route: tuple[Path, Path],
                                                              tmp_path: Path) -> None:
    """A string or a list of pairs where the API takes a dict of parameters is a ParameterError
    naming the argument: dict() made it a ValueError or TypeError about update sequences."""
    from wiloc import api

    ref, query = route
    calls = {"method_params": lambda: api.localize(query, reference=ref, method_params=given),
             "descriptor_params": lambda: api.describe(ref, descriptor_params=given)}
    calls["descriptor_params (localizer)"] = lambda: Localizer(ref, descriptor_params=given)
    calls["method_params (follow)"] = lambda: api.follow_folder(query, reference=ref, method_params=given,
                                                                out=tmp_path / "f.csv")
    for name, call in calls.items():
        with pytest.raises(ParameterError, match="must map parameter names to values \\(a dict\\), got (str|list)") as refused:
            call()
        assert refused.value.parameter == name.split()[0]
    assert not (tmp_path / "f.csv").exists()


@pytest.mark.parametrize("folders, got", [(None, "got NoneType"), (3, "got int"), (["{ref}", 3], "got a list holding int")])
def test_describe_and_vocabulary_of_no_paths_are_a_parameter_error(folders: object, got: str,
                                                                   route: tuple[Path, Path]) -> None:
    """None, a number, or a list holding one where describe and vocabulary take folders is a
    ParameterError naming ``folders``: it was Python's TypeError ('NoneType' object is not
    iterable, expected str ... not int)."""
    from wiloc import api

    ref, _ = route
    given = [str(ref) if f == "{ref}" else f for f in folders] if isinstance(folders, list) else folders
    for verb in (api.describe, api.vocabulary):
        with pytest.raises(ParameterError, match=f"a traversal's path .* or a list of them, {got}$") as refused:
            verb(given)
        assert refused.value.parameter == "folders"


def test_an_fps_beyond_any_camera_is_refused_and_the_highest_keeps_every_frame() -> None:
    """--fps 1e308 passed the check (finite, > 0) and ended in an OverflowError with a traceback
    once a frame's slot, ms x fps / 1000, became infinite; the highest fps taken keeps every frame
    of a day-long video."""
    from wiloc.sources.video import MAX_FPS, Sampling

    with pytest.raises(ParameterError, match=r"must be a number of frames per second > 0 and at most 1e\+06") as refused:
        Sampling(fps=1e308)
    assert refused.value.parameter == "fps"
    stream = [(i, i * 40.0) for i in range(0, 2_160_000, 1000)]  # 24 h at 25 frames/s, a frame of each 1000
    assert list(Sampling(fps=MAX_FPS).pick(stream)) == stream


@pytest.mark.parametrize("value", [10 ** 400, 10 ** 20, -10 ** 30])
def test_an_integer_parameter_beyond_64_bits_is_a_parameter_error(value: int) -> None:
    """Integer parameters reach compiled kernels as int64: --same-place-window 99999999999999999999
    ended in numba's OverflowError and --seed of 401 digits in float()'s, each with a traceback."""
    from wiloc.methods.registry import make_method

    for method, name in (("online", "same_place_window"), ("online", "seed"), ("catgraph", "seed")):
        with pytest.raises(ParameterError, match=r"must be a 64-bit integer \(-2\^63 to 2\^63 - 1\), got one of \d+ digits$") as refused:
            make_method(method, {name: value})
        assert refused.value.parameter == name
    assert make_method("online", {"seed": 2 ** 63 - 1}).params.seed == 2 ** 63 - 1


def test_a_seqslam_velocity_step_too_small_for_a_float_ratio_is_a_parameter_error() -> None:
    """--v-step 1e-320 made (v_max - v_min) / v_step infinite, and counting the velocities ended
    in an OverflowError with a traceback, where 1e-300 was refused as too many velocities."""
    from wiloc.methods.registry import make_method

    with pytest.raises(ParameterError, match="gives more than 1000 velocities from v_min to v_max") as refused:
        make_method("seqslam", {"v_step": 1e-320})
    assert refused.value.parameter == "v_step"


def test_a_seqslam_enhance_window_wider_than_the_map_is_the_whole_map() -> None:
    """--enhance-window 2**62 listed a shift for each of its 2**62 + 1 offsets before finding that
    none overlaps the map, filling the memory (the machine's OOM killer ended the run): a window
    wider than the map is the whole map. Run with 3 GiB of address space, so that the old way
    ends in a MemoryError here, not in the OOM killer."""
    import resource

    code = ("import numpy as np; from wiloc.methods.seqslam import enhance; "
            "rows = np.random.default_rng(0).random((2, 30)); "
            "print(np.array_equal(enhance(rows, 2 ** 62), enhance(rows, 30)))")
    limit = functools.partial(resource.setrlimit, resource.RLIMIT_AS, (3 << 30, 3 << 30))
    ran = subprocess.run([sys.executable, "-c", code], preexec_fn=limit, capture_output=True, text=True, timeout=120,
                         check=False)
    assert (ran.returncode, ran.stdout.strip()) == (0, "True"), ran.stderr[-500:]


@pytest.mark.parametrize("recall_at, got", [([50], "got 50"), ([100], "got 100"), ([0], "got 0"), ([1.5], "got 1.5"),
                                            ("5", "got str")])
def test_recall_at_beyond_the_kept_candidates_is_a_parameter_error(recall_at: object, got: str, results: Path) -> None:
    """api.evaluate's recall_at takes what --recall-at takes, whole numbers from 1 to 20: a
    results file keeps 20 candidates per frame, so Recall@50 was silently Recall@20's number on a
    larger map, and Recall@100 replaced recall at 100 % precision under its key; 0 was dropped,
    1.5 and '5' ended in TypeErrors."""
    from wiloc import api

    with pytest.raises(ParameterError, match=f"whole numbers from 1 to 20.*, {got}$") as refused:
        api.evaluate(results, api.TruthSource(), recall_at=recall_at)
    assert refused.value.parameter == "recall_at"
    assert api.evaluate(results, api.TruthSource(), recall_at=[20]).summary.as_dict()["recall_at_20"] == 1.0


@pytest.mark.parametrize("cuts, got", [([0.5, 1.5], "got 1.5"), ([float("nan")], "got nan"), (None, "got NoneType")])
def test_cuts_outside_0_1_are_a_parameter_error(cuts: object, got: str, results: Path) -> None:
    """api.evaluate's cuts take what --cuts takes: 1.5 or NaN ended in the calibration's
    ValueError, and None was read as a cut of NaN ('got [nan]')."""
    from wiloc import api

    with pytest.raises(ParameterError, match=rf"confidences in \[0, 1\], {got}$") as refused:
        api.evaluate(results, api.TruthSource(), cuts=cuts)
    assert refused.value.parameter == "cuts"


@pytest.mark.parametrize("given, parameter, message", [
    ({"truth": "aligned"}, "truth", "a TruthSource (api.TruthSource(kind='aligned', tolerance=2), ...), got str"),
    ({"precisions": "99"}, "precisions", "percentages such as 100,99, got str"),
    ({"precisions": None}, "precisions", "percentages such as 100,99, got NoneType"),
    ({"precisions": ["99"]}, "precisions", "'99' is not a percentage in (0, 100]")])
def test_compare_arguments_of_another_type_are_a_parameter_error(given: dict[str, object], parameter: str, message: str,
                                                                 results: Path) -> None:
    """A ground truth given as its command-line text ended in an AttributeError ('str' object has
    no attribute 'load'), precisions=None in a TypeError, and precisions='99' was read character
    by character: Table II for a target precision of 9 %, twice."""
    from wiloc import api

    arguments = {"truth": api.TruthSource(), **given}
    with pytest.raises(ParameterError) as refused:
        api.compare([results], arguments.pop("truth"), **arguments)
    assert (refused.value.parameter, str(refused.value)) == (parameter, f"{parameter}: {message}")


def test_cuts_recall_at_and_precisions_may_be_any_iterable_read_once(results: Path, online_results: Path) -> None:
    """Generators are read once, by the checks, and what they held is used: each run of a
    comparison gets every cut and N, not only the first run."""
    from wiloc import api

    as_lists = api.compare([results, online_results], api.TruthSource(), precisions=[100, 99], cuts=[0.5, 0.9],
                           recall_at=[1, 5])
    as_generators = api.compare([results, online_results], api.TruthSource(), precisions=iter([100, 99]),
                                cuts=(c for c in [0.5, 0.9]), recall_at=iter([1, 5]))
    assert "recall@0.9" in as_generators.cut_table and "recall_at_5" in as_generators.table1
    for table in ("table1", "table2", "cut_table"):
        assert getattr(as_generators, table).equals(getattr(as_lists, table)), table


@pytest.mark.parametrize("given, parameter, message", [
    ({"kind": "positions", "path": "q.csv", "radius": "25"}, "radius", "must be a finite number >= 0 metres, got '25'"),
    ({"kind": "pairs", "path": 3}, "path", "a file's path (text or a path object), got int"),
    ({"kind": "positions", "path": "q.csv", "ref_path": ["r.csv"], "radius": 2.0}, "ref_path",
     "a file's path (text or a path object), got list")])
def test_a_ground_truth_of_wrong_types_is_refused_as_it_is_made(given: dict[str, object], parameter: str,
                                                               message: str) -> None:
    """TruthSource(radius='25') ended in a TypeError comparing it with 0, and a path given as a
    number or a list in a TypeError only once a run was scored."""
    from wiloc.evaluation.truth_source import TruthSource

    with pytest.raises(ParameterError) as refused:
        TruthSource(**given)
    assert (refused.value.parameter, str(refused.value)) == (parameter, f"{parameter}: {message}")


@pytest.mark.parametrize("given, parameter, message", [
    ({"kind": "alignd"}, "kind", "unknown ground-truth kind 'alignd'; choose one of aligned, positions"),
    ({"kind": None}, "kind", "unknown ground-truth kind None"),
    ({"tolerance": -1}, "tolerance", "must be a whole number of frames >= 0, got -1"),
    ({"tolerance": 2.5}, "tolerance", "must be a whole number of frames >= 0, got 2.5"),
    ({"tolerance": True}, "tolerance", "must be a whole number of frames >= 0, got True"),
    ({"by": "nme"}, "by", "'name' or 'index', got 'nme'")])
def test_a_ground_truth_of_bad_values_is_refused_as_it_is_made(given: dict[str, object], parameter: str,
                                                              message: str, results: Path) -> None:
    """TruthSource(kind='alignd'), a negative tolerance or by='nme' were made, and refused only as a
    run was scored, in a WilocError (not the ParameterError a negative radius is, as it is made)."""
    from wiloc import api

    with pytest.raises(ParameterError) as refused:
        api.TruthSource(**given)
    assert refused.value.parameter == parameter and str(refused.value).startswith(f"{parameter}: {message}")
    assert api.evaluate(results, api.TruthSource(tolerance=0, by="index")).summary.frames > 0  # good values pass


def test_ground_truth_values_the_cli_refuses_are_one_line_each(results: Path) -> None:
    """The command line refuses the same mistakes itself, each in one line naming its option."""
    for args, code, message in ((["--gt", "alignd"], 2, "--gt: 'alignd' is neither a ground-truth form nor a file"),
                                (["--gt", "alignd:x.csv"], 2, "--gt: unknown ground-truth form 'alignd'"),
                                (["--tolerance", "-1"], 2, "--tolerance: input should be greater"),
                                (["--gt", "aligned:nme"], 2, "--gt: 'aligned' reads the traversals themselves")):
        ends_in_one_error(runner.invoke(app, ["evaluate", str(results), *args]), code, message)


@pytest.mark.parametrize("progress", [5, "bar"])
def test_a_progress_that_is_no_function_is_a_parameter_error(progress: object, route: tuple[Path, Path],
                                                             tmp_path: Path) -> None:
    """progress=5 ended in "TypeError: 'int' object is not callable" from deep in describing, once
    the first frames were described; it is refused before, as the other parameters are."""
    from wiloc import api

    ref, query = route
    out = tmp_path / "run.csv"
    expected = f"progress: a function progress(stage, done, total) or None, got {type(progress).__name__}"
    for call in (lambda: api.describe(ref, progress=progress), lambda: api.describe([ref, query], progress=progress),
                 lambda: api.localize(query, reference=ref, method="threshold", progress=progress, out=out)):
        with pytest.raises(ParameterError, match=f"^{re.escape(expected)}$") as refused:
            call()
        assert refused.value.parameter == "progress"
    assert not out.exists()
    seen: list[str] = []
    api.localize(query, reference=ref, method="threshold", progress=lambda stage, done, total: seen.append(stage))
    assert seen  # a function is called


def test_a_sampling_that_is_no_sampling_or_of_a_folder_map_is_a_parameter_error(route: tuple[Path, Path]) -> None:
    """sampling='2' ended in a TypeError from asdict() in describe, localize and Localizer (a
    video map's), and a Localizer's folder map took Sampling(every=2) silently, where a batch run
    refuses it: a folder's frames are all taken."""
    from wiloc import api

    ref, query = route
    for call in (lambda: api.describe(ref, sampling="2"), lambda: api.localize(query, reference=ref, sampling="2"),
                 lambda: Localizer(ref, sampling="2")):
        with pytest.raises(ParameterError, match="a Sampling .*, got str$") as refused:
            call()
        assert refused.value.parameter == "sampling"
    with pytest.raises(ParameterError, match=f"applies to video files and ROS bags only; {ref} is neither") as refused:
        Localizer(ref, sampling=api.Sampling(every=2))
    assert refused.value.parameter == "every"


@pytest.mark.parametrize("path", [None, 3])
def test_loading_a_state_given_as_no_path_is_a_parameter_error(path: object) -> None:
    """Localizer.load(None) (a path looked up and not found) ended in pathlib's TypeError."""
    expected = f"path: a saved state's file (text or a path object), got {type(path).__name__}"
    with pytest.raises(ParameterError, match=re.escape(expected)) as refused:
        Localizer.load(path)
    assert refused.value.parameter == "path"


@pytest.mark.parametrize("path, problem", [(5, "(text or a path object), got int"),
                                           ("", "the path is empty"), ("a\0b.npz", "holds a NUL character")])
def test_saving_a_state_to_no_path_is_a_parameter_error(path: object, problem: str, route: tuple[Path, Path],
                                                        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Localizer.save(5) ended in pathlib's TypeError; save("") and load("") named the current folder."""
    monkeypatch.chdir(tmp_path)
    loc = Localizer(route[0], method="threshold")
    for call in (lambda: loc.save(path), lambda: Localizer.load(path)):
        with pytest.raises(ParameterError, match=re.escape(problem)) as refused:
            call()
        assert refused.value.parameter == "path"
    assert not list(tmp_path.rglob("*.npz"))


@pytest.mark.parametrize("follow", [False, True])
def test_results_never_replace_a_file_that_is_no_results_file(follow: bool, route: tuple[Path, Path], results: Path,
                                                               tmp_path: Path) -> None:
    """-o naming one of the query's own frames (or a table of one's own) replaced it, with only the
    note 'replaced the existing results file' (a followed run refused it already, and says the same
    now); a batch run still replaces a results file (with an editor's byte-order mark too) and takes an
    empty file."""
    ref, query = route
    frame = query / "img3.png"
    kept = frame.read_bytes()
    run = ["localize", str(query), "--map", str(ref), "--method", "threshold", "--jobs", "1",
           *(["--follow", "--idle", "0.3"] if follow else [])]
    result = runner.invoke(app, [*run, "--out", str(frame)])
    ends_in_one_error(result, 1, f"{frame}: cannot write the results file: the file there is no wiloc results file")
    assert frame.read_bytes() == kept and not (query / ".img3.png.lock").exists()
    marked = tmp_path / "marked.csv"
    marked.write_bytes(b"\xef\xbb\xbf" + results.read_bytes())
    empty = tmp_path / "empty.csv"
    empty.touch()
    for out in () if follow else (results, marked, empty):
        assert runner.invoke(app, [*run, "--out", str(out)]).exit_code == 0, out
        assert out.read_text(encoding="utf-8").startswith("# wiloc-results: 1")


def test_a_sampling_without_frames_to_sample_is_a_parameter_error() -> None:
    """A Localizer in sequence mode (no map) or over a map held in memory took Sampling(every=2)
    and ignored it: neither has a video's frames to sample."""
    from wiloc import api
    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor

    spec = get_descriptor("sad")
    memory = entry_from_array(np.zeros((5, spec.length), np.uint8), [f"m{i}" for i in range(5)], spec)
    for given in (None, memory):
        with pytest.raises(ParameterError, match="applies to video files and ROS bags only; no traversal given "
                                                 "is one$") as refused:
            Localizer(given, method="catgraph", sampling=api.Sampling(every=2))
        assert refused.value.parameter == "every"
    assert Localizer(None, method="catgraph", sampling=api.Sampling()).sequence


@pytest.mark.parametrize("line, edited, message", [
    ("# method: threshold", "# method: ", "header 'method' is empty: the method that wrote the file is unknown"),
    ("# metric: l1", "# metric: l7", "header 'metric' must be one of l1, sqeuclidean, hamming, cosine, got 'l7'")])
def test_a_header_edited_to_no_method_or_an_unknown_metric_is_refused_naming_the_line(line: str, edited: str,
                                                                                      message: str, results: Path,
                                                                                      tmp_path: Path) -> None:
    """A results file whose method was edited away, or whose metric names none there is, was
    scored as any other run."""
    lines = results.read_text().splitlines()
    number = lines.index(line) + 1
    lines[number - 1] = edited
    path = tmp_path / "edited.csv"
    path.write_text("\n".join(lines) + "\n")
    ends_in_one_error(runner.invoke(app, ["evaluate", str(path)]), 1, f"{path}: line {number}: {message}")


@pytest.mark.parametrize("value", ["-3", "inf"])
def test_a_difference_no_run_on_differences_writes_is_refused_naming_the_line(value: str, results: Path,
                                                                             tmp_path: Path) -> None:
    """Every metric's differences are finite and >= 0 (only FAB-MAP's evidence gives negative
    ones, rows: fabmap); an edited -3 or inf was read silently."""
    edited = _edited(results, "difference", value, tmp_path / "edited.csv")
    line = next(i for i, text in enumerate(edited.read_text().splitlines()) if text.startswith("frame,")) + 2
    ends_in_one_error(runner.invoke(app, ["evaluate", str(edited)]), 1,
                      f"{edited}: line {line}: difference {value} is not a finite number >= 0")


@pytest.mark.parametrize("role", ["query", "map", "import"])
def test_a_results_file_given_for_descriptors_says_it_is_a_results_file(role: str, route: tuple[Path, Path],
                                                                         results: Path, tmp_path: Path) -> None:
    """A results CSV as QUERY or --map asked for --metric, as a descriptor matrix, and given one
    ended in pandas' tokenizing error; describe --import said the same."""
    ref, query = route
    args = {"query": ["localize", str(results), "--map", str(ref), "--out", str(tmp_path / "o.csv")],
            "map": ["localize", str(query), "--map", str(results), "--out", str(tmp_path / "o.csv")],
            "import": ["describe", "--import", str(results), "--metric", "l1"]}[role]
    wanted = ("holds no descriptors to import: give a descriptor matrix file" if role == "import" else
              "is not a traversal: give a folder of images, a video or a descriptor matrix file")
    ends_in_one_error(runner.invoke(app, args), 1, f"{results}: a wiloc results file {wanted}",
                      "; evaluate and compare read results files")
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("layout", ["file.npy", "file.npz", "folder"])
def test_an_empty_npy_file_to_import_is_one_line(layout: str, tmp_path: Path, cache_dir: Path) -> None:
    """An empty .npy (or an empty file named .npz, read as .npy) ended in numpy's EOFError with a
    traceback, as a folder of .npy vectors holding one did."""
    empty = tmp_path / "vectors" / "a.npy" if layout == "folder" else tmp_path / layout
    empty.parent.mkdir(exist_ok=True)
    empty.write_bytes(b"")
    given = ([str(empty.parent), "--out", str(tmp_path / "out.h5")] if layout == "folder"
             else [str(empty), "--metric", "l1"])
    ends_in_one_error(runner.invoke(app, ["describe", "--import", *given]), 1,
                      f"{empty}: not a readable .npy array (the file is empty or cut short)")
    assert not (tmp_path / "out.h5").exists()


@pytest.mark.parametrize(("metric", "value"), [("l1", 3e38), ("sqeuclidean", 1e20), ("cosine", 1e300)])
def test_descriptors_too_large_for_float32_differences_are_refused(metric: str, value: float, tmp_path: Path,
                                                                   cache_dir: Path) -> None:
    """Differences are computed in float32: a matrix whose values overflowed them (float64 beyond
    float32's range, or l1 sums and squares past it) gave infinite differences, read as no
    candidate, and localize ended with every frame undecided, exit code 0."""
    values = np.random.default_rng(0).random((6, 8)) * value
    np.save(tmp_path / "q.npy", values)
    np.save(tmp_path / "m.npy", values[::-1].copy())
    out = tmp_path / "run.csv"
    ends_in_one_error(runner.invoke(app, ["localize", str(tmp_path / "q.npy"), "--map", str(tmp_path / "m.npy"),
                                          "--metric", metric, "--method", "threshold", "--out", str(out)]),
                      1, f"{tmp_path / 'q.npy'}: values up to ", f"{metric} differences of rows of 8 values would "
                                                                  "pass float32's range")
    assert not out.exists()


def test_a_catgraph_mode_window_wider_than_the_map_is_the_whole_map() -> None:
    """--mode-window 10**6 (particles x its width of nodes to sum) ended in a MemoryError, and
    2**62 wrapped the width around int64 into a buffer too small for the nodes written to it: a
    window wider than the map is the whole map, with the same decisions. Run with 3 GiB of
    address space, as the seqslam window's test."""
    import resource

    code = ("import numpy as np; from wiloc.localization.array_run import run_on_rows; "
            "from wiloc.methods.catgraph.filter import CatGraph; rng = np.random.default_rng(0); "
            "rows, ref = rng.random((20, 30)), rng.random((30, 30)); "
            "runs = [run_on_rows(CatGraph(mode_window=w), iter(rows), 20, map_self=ref, exclude_recent=2) "
            "for w in (30, 10 ** 6, 2 ** 62)]; "
            "print(all(np.array_equal(r.match, runs[0].match) and np.array_equal(r.confidence, runs[0].confidence) "
            "for r in runs))")
    limit = functools.partial(resource.setrlimit, resource.RLIMIT_AS, (3 << 30, 3 << 30))
    ran = subprocess.run([sys.executable, "-c", code], preexec_fn=limit, capture_output=True, text=True, timeout=300,
                         check=False)
    assert (ran.returncode, ran.stdout.strip()) == (0, "True"), ran.stderr[-500:]


def test_a_catgraph_contrast_window_beyond_its_bound_is_a_parameter_error(route: tuple[Path, Path],
                                                                          tmp_path: Path) -> None:
    """The contrast normalisation steps over each row's window before its running sums: its time
    grows with the window, unbounded (--contrast-window 10**9 ran for minutes on a map of 30
    frames, 2**62 for ever). Beyond the map the window still changes the values (the row's ends
    extended), so it is bounded, not clipped."""
    from wiloc.methods.registry import make_method

    ref, query = route
    with pytest.raises(ParameterError, match=r"must lie in \[1, 100000\], got 1000000000$") as refused:
        make_method("catgraph", {"contrast_window": 10 ** 9})
    assert refused.value.parameter == "contrast_window"
    ends_in_one_error(runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "catgraph",
                                          "--contrast-window", str(2 ** 62), "--out", str(tmp_path / "o.csv")]),
                      2, f"--contrast-window: must lie in [1, 100000], got {2 ** 62}")
    assert make_method("catgraph", {"contrast_window": 100_000}).params.contrast_window == 100_000


@pytest.mark.parametrize("command", ["evaluate", "compare"])
def test_metrics_curves_over_a_results_file_read_are_a_usage_error(command: str, results: Path, tmp_path: Path) -> None:
    """--csv m.csv writes its curves to m-curves.csv beside it: a results file of that name among
    those read was replaced by the curves (with only the note 'replaced the existing file')."""
    read = results.rename(tmp_path / "m-curves.csv")
    before = read.read_bytes()
    ends_in_one_error(runner.invoke(app, [command, str(read), "--csv", str(tmp_path / "m.csv")]), 2,
                      f"--csv: {read} is one of the results files read; give each output a file of its own")
    assert read.read_bytes() == before and not (tmp_path / "m.csv").exists()


def test_a_run_s_figure_over_another_output_is_a_usage_error(results: Path, online_results: Path,
                                                            tmp_path: Path) -> None:
    """With several runs --matrix-plot m.png draws m-RESULTS.png for each: --pr-plot m-run.png was
    written, then replaced by run.csv's matrix, both said 'wrote m-run.png'."""
    pr = tmp_path / f"m-{results.stem}.png"
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), str(online_results), "--pr-plot", str(pr),
                                          "--matrix-plot", str(tmp_path / "m.png")]), 2,
                      f"--matrix-plot: {pr} is --pr-plot's file; give each output a file of its own")
    assert not list(tmp_path.glob("*.png"))


def test_a_blank_line_inside_a_results_table_is_refused_naming_it(online_results: Path, tmp_path: Path) -> None:
    """pandas skipped a blank line between rows, so the rows after it were named one line early
    (a confidence edited on line 28 was 'line 27'); blank lines an editor leaves at the end pass."""
    lines = online_results.read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("frame,")) + 1
    edited = tmp_path / "blank.csv"
    edited.write_text("\n".join(lines[:first + 4] + [""] + lines[first + 4:]) + "\n")
    ends_in_one_error(runner.invoke(app, ["evaluate", str(edited)]), 1,
                      f"{edited}: line {first + 5}: a blank line in the table, where a run writes none")
    ended = tmp_path / "ended.csv"
    ended.write_text("\n".join(lines) + "\n\n\n")
    assert runner.invoke(app, ["evaluate", str(ended)]).exit_code == 0


def test_a_run_s_figure_that_no_file_can_take_is_refused_before_any_output(results: Path, online_results: Path,
                                                                            tmp_path: Path) -> None:
    """With several runs --matrix-plot m.png draws m-RESULTS.png for each; a folder there was
    found only when that figure was written, after --pr-plot's and the first run's ('note
    replaced the existing file' said of the folder)."""
    (tmp_path / f"m-{online_results.stem}.png").mkdir()
    ends_in_one_error(runner.invoke(app, ["evaluate", str(results), str(online_results), "--pr-plot",
                                          str(tmp_path / "pr.png"), "--matrix-plot", str(tmp_path / "m.png")]), 2,
                      f"--matrix-plot: {tmp_path / f'm-{online_results.stem}.png'}: it is not a regular file")
    assert not [p for p in tmp_path.glob("*.png") if p.is_file()]



@pytest.mark.parametrize("shape", [(1, 1), (4, 100)])
def test_an_orb_vocabulary_of_an_image_a_pixel_thin_is_one_line(shape: tuple[int, int], tmp_path: Path,
                                                                 cache_dir: Path) -> None:
    """ORB's image pyramid cannot shrink an image one pixel high (1 x 1, or 4 x 100 shrunk to
    --max-side 16 as 1 x 16): OpenCV's resize assertion ended vocabulary --feature orb with a
    traceback. Such an image has no features, as a flat one."""
    (tmp_path / "thin").mkdir()
    cv2.imwrite(str(tmp_path / "thin" / "a.png"),
                np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8))
    ends_in_one_error(runner.invoke(app, ["vocabulary", str(tmp_path / "thin"), "--feature", "orb", "--words", "2",
                                          "--max-side", "16"]),
                      1, f"{tmp_path / 'thin'}: no local features in any training image")


def test_a_model_plot_of_an_online_run_without_its_model_line_is_one_line(online_results: Path, tmp_path: Path) -> None:
    """An online results file without its '# model:' line is read (and scored) as any other; asked
    for its --model-plot, compare ended in an AttributeError drawing the model it has not."""
    edited = tmp_path / "no-model.csv"
    edited.write_text("".join(line for line in online_results.read_text().splitlines(keepends=True)
                              if not line.startswith("# model:")))
    ends_in_one_error(runner.invoke(app, ["compare", str(edited), "--model-plot", str(tmp_path / "fig1.png")]), 2,
                      "--model-plot: applies to online and trained runs with a model; none of the results is one")
    assert not (tmp_path / "fig1.png").exists()


def test_a_run_of_a_method_registered_elsewhere_is_read_with_confidences_in_0_1(results: Path, tmp_path: Path) -> None:
    """A method a program of its own registers (docs/architecture.md) writes results files that
    the installed wiloc evaluate reads: its confidences are checked against [0, 1], as no
    registered method's bounds apply."""
    text = results.read_text().replace("# method: threshold", "# method: ratio")
    path = tmp_path / "day_left-sad-ratio.csv"
    path.write_text(text)
    assert runner.invoke(app, ["evaluate", str(path)]).exit_code == 0
    edited = _edited(path, "confidence", "7.5", tmp_path / "edited.csv")
    result = runner.invoke(app, ["evaluate", str(edited)])
    assert result.exit_code == 1 and "confidence 7.5" in result.output, result.output


@pytest.mark.parametrize(("given", "parameter", "message"), [
    ({"path": None}, "path", "a file's path (text or a path object), got NoneType"),
    ({"names": ["a.png"]}, "names", "a file's path (text or a path object), got list"),
    ({"out": 5}, "out", "a file's path (text or a path object), got int"),
    ({"out": "x.h5", "prefix": 5}, "prefix", "the text frame names begin with (db/, query/), got int")])
def test_import_arguments_of_another_type_are_a_parameter_error(given: dict[str, object], parameter: str,
                                                                 message: str, tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """api.import_descriptors given no path, a list of names, a number as out or prefix ended in
    pathlib's or str.startswith's TypeError."""
    from wiloc import api

    monkeypatch.chdir(tmp_path)
    np.save(tmp_path / "m.npy", np.random.default_rng(0).random((3, 4)).astype(np.float32))
    with pytest.raises(ParameterError, match=re.escape(message)) as raised:
        api.import_descriptors(**{"path": tmp_path / "m.npy", "metric": "l1", **given})
    assert raised.value.parameter == parameter and not (tmp_path / "x.h5").exists()


def test_a_vocabulary_max_features_beyond_a_c_int_is_a_usage_error(tmp_path: Path, cache_dir: Path) -> None:
    """OpenCV's detectors take the feature cap as a C int: --max-features 3000000000 ended in
    cv2's 'integer won't fit into a C int' with a traceback, after the images were read."""
    (tmp_path / "train").mkdir()
    cv2.imwrite(str(tmp_path / "train" / "a.png"), np.random.default_rng(0).integers(0, 256, (64, 64), dtype=np.uint8))
    ends_in_one_error(runner.invoke(app, ["vocabulary", str(tmp_path / "train"), "--max-features", "3000000000"]),
                      2, "--max-features: must lie in [1, 2147483647], got 3000000000")


@pytest.mark.parametrize("flag", ["no", None, 0])
def test_compare_global_thresholds_of_another_type_are_a_parameter_error(flag: object, results: Path) -> None:
    """global_thresholds='no' was read as true (Table II computed), None and 0 as false."""
    from wiloc import api

    with pytest.raises(ParameterError, match=f"True or False, got {type(flag).__name__}$") as refused:
        api.compare([results], api.TruthSource(), global_thresholds=flag)
    assert refused.value.parameter == "global_thresholds"


@pytest.mark.parametrize("command", ["evaluate", "compare"])
def test_a_folder_given_as_results_is_said_to_be_a_folder(command: str, tmp_path: Path) -> None:
    """A folder given to evaluate or compare was said not to exist, which it does."""
    ends_in_one_error(runner.invoke(app, [command, str(tmp_path)]), 1,
                      f"{tmp_path}: a folder, not a results file", "runs/day_left-sad-online.csv")


def test_a_vocabulary_key_the_cache_does_not_hold_is_a_usage_error(tmp_path: Path, cache_dir: Path) -> None:
    """--vocabulary takes a file or a key from `wiloc vocabulary`: a key the cache does not hold is a
    wrong option value (exit code 2), and a path that is no file a missing file (exit code 1)."""
    (tmp_path / "train").mkdir()
    cv2.imwrite(str(tmp_path / "train" / "a.png"), np.random.default_rng(0).integers(0, 256, (64, 64), dtype=np.uint8))
    describe = ["describe", str(tmp_path / "train"), "--descriptor", "bow", "--vocabulary"]
    ends_in_one_error(runner.invoke(app, [*describe, "nosuchkey"]), 2,
                      "--vocabulary: 'nosuchkey' is neither a vocabulary file nor the key of one in the cache")
    ends_in_one_error(runner.invoke(app, [*describe, str(tmp_path / "v.npz")]), 1,
                      f"--vocabulary: {tmp_path / 'v.npz'}: file does not exist")
    ends_in_one_error(runner.invoke(app, [*describe, str(tmp_path / "train")]), 1,
                      f"--vocabulary: {tmp_path / 'train'}: a folder, not a vocabulary file")


def test_a_results_file_given_to_describe_is_said_to_be_one(results: Path, tmp_path: Path) -> None:
    """describe R.csv, and a vocabulary or api.describe of it, said 'not a folder': neither what the
    file is nor what they take."""
    from wiloc import api

    ends_in_one_error(runner.invoke(app, ["describe", str(results)]), 1,
                      f"{results}: a wiloc results file is not a traversal: describe takes folders of images, video "
                      "files and ROS bags, and descriptor matrices with --import; evaluate and compare read results files")
    (tmp_path / "one.png").write_bytes(b"")
    ends_in_one_error(runner.invoke(app, ["describe", str(tmp_path / "one.png")]), 1,
                      "one.png: an image file is not a traversal: describe takes folders of images")
    ends_in_one_error(runner.invoke(app, ["vocabulary", str(results)]), 1,
                      f"{results}: a wiloc results file is not a traversal: give a folder of images; evaluate")
    with pytest.raises(WilocError, match="a wiloc results file is not a traversal: give a folder of images"):
        api.describe(results)


@pytest.mark.parametrize(("metric", "value"), [("l1", 1e38), ("sqeuclidean", 1e20)])
def test_rows_in_memory_too_large_for_float32_differences_are_refused(metric: str, value: float) -> None:
    """A matrix file of such values is refused (its differences, in float32, overflowed); a map's
    rows held in memory and a row observed were taken: every frame undecided, no error."""
    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor

    spec, rows = get_descriptor("external", metric=metric, length=8), np.random.default_rng(0).random((30, 8))
    names = [f"m{i}" for i in range(30)]
    with pytest.raises(WilocError, match=f"values up to .*: {metric} differences of rows of 8 values would pass "
                                         "float32's range") as refused:
        entry_from_array(rows * value, names, spec, source="my map")
    assert refused.value.where == "my map"
    loc = Localizer(entry_from_array(rows, names, spec), descriptor="external", metric=metric, method="threshold")
    with pytest.raises(WilocError, match=f"values up to .*: {metric} differences") as refused:
        loc.observe(rows[3] * value)
    assert refused.value.where == "observe"
    assert loc.observe(rows[3]).match == 3


def test_describing_images_with_the_external_descriptor_says_what_external_is(route: tuple[Path, Path]) -> None:
    """api.describe(folder, 'external') said 'external metric must be one of ...; got None', a
    parameter no one can give it there (the command line said what external is already)."""
    from wiloc import api

    with pytest.raises(ParameterError, match="'external' names descriptors computed elsewhere, which are not "
                                             "described: import their matrix file") as refused:
        api.describe(route[0], "external")
    assert refused.value.parameter == "descriptor"


def test_names_of_a_map_in_memory_are_plain_text_and_one_text_is_no_list_of_names() -> None:
    """Names given as a numpy array stayed numpy's text in the map and in each decision; one text
    given as the names was taken letter by letter, and refused as a matter of shape."""
    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor

    spec, rows = get_descriptor("external", metric="l1", length=8), np.random.default_rng(0).random((3, 8))
    entry = entry_from_array(rows, np.array(["a", "b", "c"]), spec)
    assert [type(name) for name in entry.names] == [str] * 3
    decision = Localizer(entry, descriptor="external", metric="l1", method="threshold").observe(rows[1],
                                                                                             name=np.str_("q"))
    assert type(decision.frame) is str and type(decision.match_name) is str
    with pytest.raises(WilocError, match="names: one name per row .*got the text 'abc'"):
        entry_from_array(rows, "abc", spec)


@pytest.mark.parametrize("command", ["evaluate", "compare"])
def test_a_bad_frames_slice_is_refused_before_any_results_file_is_read(tmp_path: Path, command: str) -> None:
    """A step, or text that is no slice, is one usage error naming --frames, though the results
    file is missing too: the slice is checked before any file is read (the library's the same)."""
    from wiloc import api

    missing = tmp_path / "missing.csv"
    ends_in_one_error(runner.invoke(app, [command, str(missing), "--frames", "1:2:3"]), 2,
                      "--frames: '1:2:3' (a step is not taken): give START:STOP")
    ends_in_one_error(runner.invoke(app, [command, str(missing), "--frames", "first"]), 2, "--frames: 'first'")
    with pytest.raises(ParameterError, match="a slice of whole numbers without a step") as refused:
        api.compare([missing], api.TruthSource(kind="aligned"), frames=20)
    assert refused.value.parameter == "frames"


def test_a_map_in_memory_is_a_copy_of_the_callers_rows() -> None:
    """entry_from_array kept the caller's array: a buffer reused after the map was made changed the
    running Localizer's matches while the map's digest still named the old values."""
    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor

    spec = get_descriptor("sad")
    rows = np.random.default_rng(0).integers(0, 256, (60, spec.length)).astype(np.uint8)
    entry = entry_from_array(rows, [f"m{i:03d}" for i in range(60)], spec)
    loc, query, digest = Localizer(entry, method="threshold"), rows[10].copy(), entry.digest
    assert loc.observe(query).match_name == "m010"
    rows[:] = rows[::-1].copy()
    assert loc.observe(query, name="again").match_name == "m010" and entry.digest == digest
    assert not entry.data.flags.writeable


@pytest.mark.parametrize("dtype", ["bool", "complex64", "int32", "U3"])
def test_an_external_descriptor_of_values_that_are_not_floats_is_refused(dtype: str) -> None:
    """external's dtype was checked only to be uint8 for hamming: bool made every row True (each
    query matched the map's first frame at confidence 1), text failed inside numpy."""
    from wiloc.descriptors.registry import get_descriptor

    with pytest.raises(ValueError, match=f"external dtype {np.dtype(dtype).name}: .*other metrics need floats"):
        get_descriptor("external", metric="l1", length=16, dtype=dtype)
    assert get_descriptor("external", metric="l1", length=16, dtype="float64").dtype == np.float64


def test_evaluations_compare_equal_and_recall_at_from_numpy_gives_plain_keys(results: Path) -> None:
    """Two equal summaries raised numpy's ambiguous truth value (their PR curves' arrays), and
    recall_at as a numpy array gave np.int64 keys that json.dumps refused."""
    from wiloc import api

    first = api.evaluate(results, api.TruthSource(), recall_at=np.array([5, 1, 5])).summary
    again = api.evaluate(results, api.TruthSource(), recall_at=[1, 5]).summary
    assert first == again and first.curve == again.curve
    assert [type(n) for n in first.recall_at_n] == [int]
    json.dumps(first.recall_at_n)
    assert first.curve != replace(first.curve, tp=first.curve.tp + 1)


def test_method_parameters_that_are_no_mapping_are_named() -> None:
    """Online("bins") was dict()'s ValueError about update sequences."""
    from wiloc.methods.online import Online

    for given in ("bins", 5):
        with pytest.raises(ParameterError) as err:
            Online(given)  # type: ignore[arg-type]
        assert err.value.parameter == "params"


@pytest.mark.parametrize("name, given", [("method", ["catgraph"]), ("method", None), ("descriptor", ["sad"]),
                                         ("map_odometry", 5), ("odometry", 5)])
def test_names_and_paths_of_another_type_are_a_parameter_error(name: str, given: object,
                                                               route: tuple[Path, Path], tmp_path: Path) -> None:
    """method=['catgraph'] and descriptor=['sad'] ended in a TypeError (unhashable), odometry=5 in
    pathlib's; method=None was said to be an unknown method 'None': each is a ParameterError
    naming the parameter and the type given, in the Localizer and in localize alike."""
    from wiloc import api

    ref, query = route
    csv = tmp_path / "odometry.csv"
    csv.write_text("".join(f"img{i}.png,{i}\n" for i in range(30)))
    setup = {"method": "catgraph", "map_odometry": csv, name: given}
    calls = [lambda: api.localize(query, reference=ref, cache=Cache(tmp_path / "cache"),
                                  **{"odometry": csv, **setup})]
    if name != "odometry":  # a Localizer is given the query's odometry frame by frame
        calls.append(lambda: Localizer(ref, cache=Cache(tmp_path / "cache"), **setup))
    for call in calls:
        with pytest.raises(ParameterError) as err:
            call()
        assert err.value.parameter == name and err.value.problem.endswith(f"got {type(given).__name__}")


@pytest.mark.parametrize("where", ["query", "map"])
def test_a_symbolic_link_loop_given_as_a_traversal_is_one_error(where: str, route: tuple[Path, Path],
                                                                 tmp_path: Path) -> None:
    """A query or map that is a symbolic link loop ended in a RuntimeError's traceback (resolving it
    to see whether the query is the map)."""
    ref, query = route
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    args = [str(tmp_path / "a"), "--map", str(ref)] if where == "query" else [str(query), "--map", str(tmp_path / "a")]
    result = runner.invoke(app, ["localize", *args, "--method", "threshold", "--out", str(tmp_path / "o.csv")])
    ends_in_one_error(result, 1, str(tmp_path / "a"))
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("second, problem", [("missing", "folder does not exist"), ("empty", "no image files"),
                                             ("query/img0.png", "an image file is not a traversal"),
                                             ("run.csv", "a wiloc results file is not a traversal")])
def test_a_bad_later_query_fails_before_the_first_is_localized(second: str, problem: str, route: tuple[Path, Path],
                                                               results: Path, tmp_path: Path) -> None:
    """`localize q nonexist --out multi/` localized q and wrote its results before failing on the
    second query: each query is checked (it exists and is a folder of images, a video, a ROS bag
    or a descriptor matrix file) before any is described, as the options are."""
    ref, query = route
    (tmp_path / "empty").mkdir()
    out = tmp_path / "multi"
    result = runner.invoke(app, ["localize", str(query), str(tmp_path / second), "--map", str(ref),
                                 "--method", "catgraph", "--out", f"{out}/", "--json"])
    ends_in_one_error(result, 1, f"error: {tmp_path / second}: {problem}")
    assert result.stdout == "" and not (out.exists() and any(out.iterdir()))
