"""Live use on a robot: a Gardens Point walk played frame by frame through a ``wiloc.Localizer``.

The query walk (``day_left``, or ``night_right``) arrives one frame at a time, as a camera
delivers it, against the map ``day_right`` (descriptor ``sad``, method ``catgraph``, seed 0). Each
decision is printed as it comes: the frame, its match, the confidence, P(new place) and the CPU
milliseconds ``observe`` took (``--quiet``: none of these lines). Halfway the localizer's state is
saved, the localizer dropped and loaded back from the file, as a robot restarted mid-route, and the
run goes on. At the end:

- the decisions are checked against an uninterrupted run of the same frames (the resumed run
  must make the same ones);
- the live run's results (``Localizer.results(query=...)``) are scored with ``wiloc.api.evaluate``
  against the aligned ground truth (+-2 frames, as examples/gardens_point.py): R@1, AP, ECE and
  precision at confidence 0.9, side by side with a batch ``wiloc.api.localize`` of the same walk,
  and the two runs' rows are compared;
- the CPU time per frame (median and 95th percentile) says the rate a robot can sustain.

What a frame is (``--frames``): ``read`` (the default) hands ``observe`` the 8-bit gray array
``Localizer.read`` decodes, OpenCV's reduced-size JPEG decode that the descriptor cache and so the
batch run make: an image array, as a driver gives one, and the same pixels, so the live run must
equal the batch run exactly (``sad`` and ``brisk-gist``'s differences are integer sums, ``gist``'s
summed in float64 and rounded once: the same frame by frame as in blocks). ``path`` hands it the file's path (the same decode, inside
``observe``). ``bgr`` hands it ``cv2.imread``'s full-size BGR array, as a camera driver (or
``cv_bridge``'s ``bgr8``) delivers frames: ``observe`` converts it to gray and describes it, which
gives other descriptors than the files' reduced decode (docs/guide.md, "Which array"), so its
decisions are compared with the batch run's but may differ from them.

Writes into ``--out``: the saved state (``state.npz``), the live run's results file (which
``wiloc evaluate`` reads) and ``summary.json``. Exits with 1 when the resumed run, or the batch
run where it must agree, decided otherwise than the live run.

    python examples/live.py [DATA] [--out FOLDER] [--query day_left|night_right] [--method catgraph]
                            [--descriptor sad] [--seed 0] [--frames read|path|bgr] [--quiet]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd
from numpy.typing import NDArray
from protocol import _finite, aligned, common_parser, localize, one_line_errors, output_folder, require, say_written

import wiloc
from wiloc import api
from wiloc.atomic import written_whole
from wiloc.cli.core import error
from wiloc.decisions import Decision
from wiloc.errors import EXIT_CLOSED_OUTPUT
from wiloc.evaluation.results import Results
from wiloc.methods.registry import method_class
from wiloc.sources.frames import list_traversal

TOLERANCE = 2  # frames, as examples/gardens_point.py
CUT = 0.9  # the confidence a robot acts on, here
METHODS = ("catgraph", "online", "threshold", "seqslam")  # those that need nothing but a map
FRAMES = ("read", "path", "bgr")
Frame = NDArray[np.uint8] | Path


def say(text: str) -> None:
    """One line of output, never wrapped (a log line per frame, read as it comes)."""
    print(text, flush=True)


def parse_args() -> argparse.Namespace:
    """The command line: the data folder and output folder as the other examples take them, and
    what to play."""
    parser = common_parser("live", __doc__.splitlines()[0])
    parser.add_argument("--query", default="day_left", choices=("day_left", "night_right"),
                        help="the Gardens Point walk played live against day_right (default: %(default)s)")
    parser.add_argument("--method", default="catgraph", choices=METHODS, help="(default: %(default)s)")
    parser.add_argument("--descriptor", default="sad", choices=("sad", "gist", "brisk-gist"),
                        help="(default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0,
                        help="random seed of the methods that draw (catgraph, online) (default: %(default)s)")
    parser.add_argument("--frames", default="read", choices=FRAMES,
                        help="what observe is handed: the cache's gray decode as an array, the file's path, "
                             "or a full-size BGR array as a camera driver gives (default: %(default)s)")
    parser.add_argument("--quiet", action="store_true", help="no line per frame")
    return parser.parse_args()


@dataclass
class Timing:
    """Per frame: CPU milliseconds to get the frame (a decode, but for ``path``) and to decide it."""

    get_frame: list[float]
    observe: list[float]

    def as_dict(self) -> dict[str, dict[str, float]]:
        """Median, 95th percentile and most of each, as a rate is planned from them."""
        return {key: {"median_ms": float(np.median(values)), "p95_ms": float(np.percentile(values, 95)),
                      "max_ms": float(np.max(values))}
                for key, values in (("get_frame", self.get_frame), ("observe", self.observe))}


def frame_source(loc: wiloc.Localizer, frames: str) -> Callable[[Path], Frame]:
    """How a frame arrives (``--frames``): an array the driver decoded, or the file's path."""
    if frames == "read":
        return loc.read
    if frames == "bgr":
        return lambda path: cv2.imread(str(path), cv2.IMREAD_COLOR)
    return lambda path: path


def play(loc: wiloc.Localizer, paths: Sequence[Path], source: Callable[[Path], Frame], timing: Timing | None,
         show: bool) -> None:
    """Hand ``paths`` to ``loc`` one by one, each frame named by its file; print each decision."""
    for path in paths:
        started = time.process_time()
        frame = source(path)
        decoded = time.process_time()
        decision = loc.observe(frame, name=path.name)
        done = time.process_time()
        if timing is not None:
            timing.get_frame.append(1000 * (decoded - started))
            timing.observe.append(1000 * (done - decoded))
        if show:
            say(decision_line(decision, 1000 * (done - decoded)))


def decision_line(d: Decision, ms: float) -> str:
    """One frame's decision as the live view prints it."""
    confidence = "-" if math.isnan(d.confidence) else f"{d.confidence:.3f}"
    new_place = "-" if math.isnan(d.new_place) else f"{d.new_place:.3f}"
    return (f"{d.frame}  match {d.match_name or '-':<14} confidence {confidence:<6} "
            f"P(new place) {new_place:<6} {ms:5.1f} ms CPU")


def same_rows(a: pd.DataFrame, b: pd.DataFrame) -> int:
    """How many frames two runs' results rows decide alike (every column equal, NaN equal to NaN)."""
    if list(a.columns) != list(b.columns) or len(a) != len(b):
        return 0
    equal = (a.to_numpy() == b.to_numpy()) | (a.isna().to_numpy() & b.isna().to_numpy())
    return int(equal.all(axis=1).sum())


def metrics(evaluation: api.Evaluation) -> dict[str, float]:
    """The numbers a robot builder reads off a run."""
    summary, calibration = evaluation.summary.as_dict(), evaluation.calibration.row()
    return {"R@1": summary["recall_at_1"], "AP": summary["auc"], "ECE": calibration["ece"],
            f"precision@{CUT:g}": calibration[f"precision@{CUT:g}"], f"recall@{CUT:g}": calibration[f"recall@{CUT:g}"]}


def render(summary: dict[str, Any]) -> str:
    """The live run's metrics beside the batch run's (None: no frame counted), as a markdown table."""
    lines = ["| metric | live | batch | equal |", "|---|---:|---:|:---:|"]
    for key, live in summary["live"].items():
        batch = summary["batch"][key]
        shown = ["-" if value is None else f"{value:.4f}" for value in (live, batch)]
        lines.append(f"| {key} | {shown[0]} | {shown[1]} | {'yes' if live == batch else 'no'} |")
    return "\n".join(lines)


def live_run(loc: wiloc.Localizer, paths: Sequence[Path], frames: str, state: Path,
             show: bool) -> tuple[wiloc.Localizer, Timing, dict[str, float]]:
    """Play ``paths`` through ``loc``, restarting halfway from its saved ``state``: the localizer
    that finished, the CPU time per frame and what the restart took."""
    timing, half = Timing([], []), len(paths) // 2
    play(loc, paths[:half], frame_source(loc, frames), timing, show)
    started = time.perf_counter()
    loc.save(state)
    saved = time.perf_counter()
    del loc  # the robot restarts
    loc = wiloc.Localizer.load(state)
    loaded = time.perf_counter()
    restart = {"after_frame": half, "state_kb": state.stat().st_size / 1024, "save_ms": 1000 * (saved - started),
               "load_ms": 1000 * (loaded - saved)}
    say(f"restart after frame {half}: saved {state} ({restart['state_kb']:.0f} kB, {restart['save_ms']:.0f} ms), "
        f"dropped the localizer, loaded it ({restart['load_ms']:.0f} ms)")
    play(loc, paths[half:], frame_source(loc, frames), timing, show)
    return loc, timing, restart


def agreement(live: pd.DataFrame, other: pd.DataFrame, what: str) -> dict[str, int]:
    """How many frames ``other`` decided as the live run did: every column alike, and the match."""
    counts = {"frames": len(live), "rows_alike": same_rows(live, other),
              "matches_alike": int((live["match"].to_numpy() == other["match"].to_numpy()).sum())
              if len(live) == len(other) else 0}
    say(f"live run against {what}: {counts['rows_alike']} of {counts['frames']} frames decided alike in every "
        f"column ({', '.join(live.columns[1:])}), {counts['matches_alike']} matches alike")
    return counts


def reruns(live: Results, reference: Path, query: Path, paths: Sequence[Path], setup: dict[str, Any],
           params: dict[str, Any], frames: str) -> tuple[dict[str, int], api.LocalizeRun, dict[str, int], bool]:
    """The same frames decided by an uninterrupted localizer (``setup``) and by a batch run
    (``params``: the method's): how far each agrees with the live run, the batch run, and whether
    it must agree (exact differences)."""
    uninterrupted = wiloc.Localizer(reference, **setup)
    play(uninterrupted, paths, frame_source(uninterrupted, frames), None, False)
    resumed = agreement(live.frames, uninterrupted.results(query=query).frames, "an uninterrupted one")
    batch = localize(query, reference=reference, descriptor=setup["descriptor"], method=setup["method"],
                     method_params=params)
    batched = agreement(live.frames, batch.results.frames, f"a batch wiloc.api.localize of {query.name}")
    # Every descriptor's differences are the same frame by frame as in the batch run's blocks
    # (docs/guide.md); full-size BGR arrays are described otherwise than the files.
    exact = frames != "bgr"
    if not exact:
        say("(not checked: full-size BGR arrays give other descriptors than the files' reduced gray decode the "
            "batch run describes; docs/guide.md, Frame by frame)")
    return resumed, batch, batched, exact


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Play the walk live with a restart halfway, check it, score it against the batch run."""
    root = args.data / "gardens-point-walking"
    reference, query = root / "day_right", root / args.query
    require([reference, query])
    paths = [query / name for name in list_traversal(query).frame_names]
    params = {"seed": args.seed} if "seed" in method_class(args.method).Params.create().as_dict() else {}
    setup = {"descriptor": args.descriptor, "method": args.method, **params}
    output_folder(args.out)
    say(f"live: {query.name} against {reference.name}, {args.descriptor}, {args.method}"
        f"{''.join(f', {k} {v}' for k, v in params.items())}, frames as {args.frames}, {len(paths)} frames")
    started = time.perf_counter()
    loc = wiloc.Localizer(reference, **setup)  # describes the map unless the cache holds it
    ready_ms = 1000 * (time.perf_counter() - started)
    say(f"map ready: {len(loc.map_names)} frames, {ready_ms:.0f} ms")
    loc, timing, restart = live_run(loc, paths, args.frames, args.out / "state.npz", not args.quiet)
    live = loc.results(query=query)
    live_file = live.save(args.out / f"{query.name}-{args.descriptor}-{args.method}.csv")

    resumed, batch, batched, exact = reruns(live, reference, query, paths, setup, params, args.frames)
    truth = aligned(TOLERANCE)
    summary = _finite({
        "experiment": "live", "map": reference.name, "query": query.name, "descriptor": args.descriptor,
        "method": args.method, "params": params, "frames_as": args.frames,
        "ground_truth": f"aligned, +-{TOLERANCE} frames", "map_ready_ms": ready_ms,
        "restart": restart, "resumed": resumed, "batch_run": batched, "batch_checked": exact,
        "live": metrics(api.evaluate(live, truth)), "batch": metrics(api.evaluate(batch, truth)),
        "cpu_ms": timing.as_dict()})
    summary["metrics_equal"] = summary["live"] == summary["batch"]
    print(render(summary))
    say(f"live metrics {'equal' if summary['metrics_equal'] else 'differ from'} the batch run's")
    say(cpu_line(summary["cpu_ms"], args.frames, len(loc.map_names)))
    with written_whole(args.out / "summary.json", "the summary") as out:
        out.write(json.dumps(summary, indent=2) + "\n")
    say_written([live_file, args.out / "state.npz", args.out / "summary.json"])
    return summary


def cpu_line(cpu_ms: dict[str, dict[str, float]], frames: str, map_frames: int) -> str:
    """The per-frame CPU time and the rate it sustains."""
    get, observe = cpu_ms["get_frame"], cpu_ms["observe"]
    rate = 1000 / (get["p95_ms"] + observe["p95_ms"])
    return (f"CPU per frame: observe median {observe['median_ms']:.2f} ms, 95th percentile {observe['p95_ms']:.2f} ms, "
            f"most {observe['max_ms']:.1f} ms; getting the frame ({frames}) median {get['median_ms']:.2f} ms, "
            f"95th percentile {get['p95_ms']:.2f} ms: at the 95th percentiles, {rate:.0f} frames/s "
            f"(map of {map_frames} frames)")


def main() -> None:
    """Run the example: one error line and its exit code for bad input, never a traceback; exit 1
    when a check fails."""
    args = parse_args()
    try:
        with one_line_errors():
            summary = run(args)
    except BrokenPipeError:  # the reader of the live log has gone (| head): what is buffered goes nowhere
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(EXIT_CLOSED_OUTPUT)
    resumed, batch = summary["resumed"], summary["batch_run"]
    if resumed["rows_alike"] < resumed["frames"] or (summary["batch_checked"] and (
            batch["rows_alike"] < batch["frames"] or not summary["metrics_equal"])):
        error("the live run decided otherwise than it should (see above)")
        sys.exit(1)


if __name__ == "__main__":
    main()
