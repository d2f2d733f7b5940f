"""`wiloc localize --follow` on Nordland: frames per second, and latency from a file's arrival to
its row in the results file.

    python benchmarks/bench_follow.py [DATA] [--methods online,catgraph] [--rate 20] [--frames 300]

Throughput: the winter frames (3576, as wiloc lists them) are put in a folder first, then `--follow --idle 1` decides
them all (descriptor included: each frame is read and described as it is decided); frames/s =
frames / (wall time - the wall time of a run on an empty folder), which pays the same start-up
and idle wait: a first, untimed run on the empty folder has described the map into the cache,
which both timed runs then read; a full folder's run that leaves a frame without a row ends the
benchmark with an error line rather than a rate. Latency: a
feeder writes the first `--frames` winter frames (the image files as wiloc lists them, in its
order: no other file, no subfolder) into an empty folder at `--rate` frames/s, each file
written whole under a temporary name and renamed (as a camera driver would); the time from the
rename to the row appearing in the results file is taken for every frame (the results file is
polled every millisecond; rows written as the run ends are taken when its end is seen, read from
the whole file once it has ended). A run that leaves a fed frame without a row ends the benchmark
with an error line rather than a latency of the frames it did decide. Medians of the per-frame
latencies, wall clock. Nordland's frames are PNGs, whose end the reader checks, so a follower
decides each at the first poll that finds it (every 0.1 s): about half a poll plus the decision.
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from rich.table import Table

from wiloc.errors import WilocError
from wiloc.evaluation.results import read_results
from wiloc.methods.registry import method_class
from wiloc.sources.frames import list_traversal

from bench_common import at_least, data_errors, last_error_line, plain_console

CLI = "import sys; from wiloc.cli import app; sys.exit(app(prog_name='wiloc'))"
#: The latency run's --idle (seconds): the frames must come faster, or it stops between two of them.
LATENCY_IDLE = 3.0


def follow(folder: Path, summer: Path, out: Path, method: str, idle: float) -> subprocess.Popen:
    """A `wiloc localize --follow` process, its output discarded but for its error output, kept in
    :func:`error_log` for :func:`ended` to report."""
    with error_log(out).open("wb") as log:  # the child holds its own copy of the file
        return subprocess.Popen([sys.executable, "-c", CLI, "localize", str(folder), "--map", str(summer),
                                 "--method", method, "--follow", "--idle", str(idle), "--out", str(out)],
                                stdout=subprocess.DEVNULL, stderr=log)


def error_log(out: Path) -> Path:
    """Where the run writing the results file ``out`` writes its error output."""
    return out.with_name(f"{out.name}.err")


def ended(method: str, code: int, out: Path, when: str) -> SystemExit:
    """The benchmark's end when the run of ``method`` writing ``out`` ended with exit code
    ``code`` ``when`` (what it had not done): one error line with the last line it said."""
    log = error_log(out)
    said = last_error_line(log.read_text(encoding="utf-8", errors="replace") if log.exists() else "", code)
    return SystemExit(f"error: wiloc localize --follow --method {method} ended with exit code {code} {when}; "
                      f"it said: {said}")


def rows(path: Path) -> int:
    """Rows written so far (lines after the header and the column line)."""
    if not path.exists():
        return 0
    lines = path.read_text(encoding="utf-8").splitlines()
    return max(0, sum(not line.startswith("#") for line in lines) - 1)


def decided_frames(out: Path) -> list[str]:
    """The frames a followed run that has ended decided, in its order: every row of its results
    file ``out``, read as wiloc reads results. A file wiloc would not read ends the benchmark with
    its one error line."""
    try:
        return read_results(out).frames["frame"].tolist()
    except WilocError as exc:
        raise SystemExit(f"error: {exc}") from None


def every_frame_decided(method: str, frames: list[str], names: list[str], where: str) -> None:
    """One error line ending the benchmark when a frame of ``frames`` (``where``: fed, in the
    folder) has no row among the ``names`` an ended run decided: a time or a rate taken over the
    frames it did decide would stand for a run it was not."""
    written = set(names)
    missing = [name for name in frames if name not in written]
    if missing:
        raise SystemExit(f"error: wiloc localize --follow --method {method} decided {len(frames) - len(missing)} "
                         f"of the {len(frames)} frames {where}; the first without a row: {missing[0]}")


class BrokenMeasure(ValueError):
    """The two timed runs did not differ by the frames alone: no rate can be taken from them."""


def frames_per_second(frames: int, full: float, empty: float) -> float:
    """``frames`` per second of their own: over the full folder's run time (``full``, seconds)
    less that of the empty folder's run (``empty``), which does the same fixed work (start-up,
    idle wait) without them. A full run no longer than the empty one shows that fixed work
    differed: BrokenMeasure, rather than a rate that means nothing."""
    if full <= empty:
        raise BrokenMeasure(f"the full folder's run ({full:.2f} s) took no longer than the empty folder's "
                            f"({empty:.2f} s), so their fixed work differed")
    return frames / (full - empty)


def throughput(winter: Path, summer: Path, method: str, work: Path) -> float:
    """Frames per second deciding a folder already full, descriptor included. The map is
    described into the cache by an untimed run first, so that neither timed run pays for it. A
    run that leaves a frame of the folder without a row ends the benchmark with one error line."""
    empty, full = work / f"empty-{method}", work / f"full-{method}"
    empty.mkdir()
    full.mkdir()
    frames = list_traversal(winter).frames
    for path in frames:
        shutil.copyfile(path, full / path.name)
    idle = 1.0
    spent: dict[str, float] = {}
    for run, folder, doing in (("warm", empty, "describing the map"), ("empty", empty, "on the empty folder"),
                               ("full", full, "on the full folder")):
        out = work / f"{run}-{method}.csv"
        start = time.perf_counter()
        code = follow(folder, summer, out, method, idle).wait()
        spent[run] = time.perf_counter() - start
        if code:  # a method that cannot run on this map ends the first run; a later failure leaves no rate
            raise ended(method, code, out, doing)
    every_frame_decided(method, [path.name for path in frames], decided_frames(work / f"full-{method}.csv"),
                        "in the folder")
    return frames_per_second(len(frames), spent["full"], spent["empty"])


def latency(winter: Path, summer: Path, method: str, work: Path, rate: float, frames: int) -> list[float]:
    """Seconds from each frame file's arrival to its row, for ``frames`` frames fed at ``rate``.
    Every wait also watches the run and the feeder, so that neither ending early leaves the
    benchmark waiting. Once the run has ended, its results file is read whole, so that the rows
    it wrote as it ended count, taken at the time its end was seen. A run that fails, or ends
    leaving a fed frame without a row, or a feed that fails, ends the benchmark with one error
    line: there is no latency to report, or one of some frames alone."""
    live, out = work / f"live-{method}", work / f"live-{method}.csv"
    live.mkdir()
    process = follow(live, summer, out, method, idle=LATENCY_IDLE)
    while not out.exists():  # the map is described and the method started: the run is ready
        if (code := process.poll()) is not None and not out.exists():
            raise ended(method, code, out, "before writing its results file")
        time.sleep(0.01)
    fed = list_traversal(winter).frames[:frames]  # as the run lists them: no other file, no subfolder
    arrived: list[float] = []
    stop, broken = threading.Event(), []

    def feed() -> None:
        for path in fed:
            if stop.is_set():
                return
            tmp = live / f".{path.name}.part"
            try:
                shutil.copyfile(path, tmp)
                os.replace(tmp, live / path.name)
            except OSError as exc:
                broken.append(f"error: feeding {path} to wiloc localize --follow --method {method}: {exc}")
                return
            arrived.append(time.perf_counter())
            stop.wait(1.0 / rate)
    feeder = threading.Thread(target=feed)
    feeder.start()
    decided: list[float] = []
    while len(decided) < len(fed) and process.poll() is None and not broken:
        n = rows(out)
        decided.extend([time.perf_counter()] * (n - len(decided)))
        time.sleep(0.001)
    stop.set()
    feeder.join()
    if broken:
        process.terminate()
        process.wait()
        raise SystemExit(broken[0])
    code = process.wait()
    seen = time.perf_counter()
    if code:
        raise ended(method, code, out, f"after deciding {rows(out)} of the {len(arrived)} frames fed")
    names = decided_frames(out)
    decided.extend([seen] * (len(names) - len(decided)))  # written as the run ended, after the last poll
    if not decided:
        raise SystemExit(f"error: wiloc localize --follow --method {method} decided none of the {len(arrived)} "
                         f"frames fed before {LATENCY_IDLE:g} s without a new frame ended it")
    every_frame_decided(method, [path.name for path in fed[:len(arrived)]], names, "fed")
    return [d - a for a, d in zip(arrived, decided)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", nargs="?", type=Path,
                        default=Path(os.environ.get("WILOC_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data"))
    parser.add_argument("--methods", default="online,catgraph")
    parser.add_argument("--rate", type=float, default=20.0,
                        help=f"frames per second fed for the latency (more than one per {LATENCY_IDLE:g} s)")
    parser.add_argument("--frames", type=int, default=300, help="frames fed for the latency")
    args = parser.parse_args()
    at_least(parser, "--frames", args.frames)
    if not args.rate * LATENCY_IDLE > 1:  # nan too; slower, the run stops after the first frame and the feed goes on alone
        parser.error(f"--rate must exceed one frame per {LATENCY_IDLE:g} s (the followed run stops after "
                     f"{LATENCY_IDLE:g} s without a new frame), got {args.rate:g}")
    try:
        for method in args.methods.split(","):
            method_class(method)
    except WilocError as exc:
        parser.error(f"--methods: {exc.problem}")
    root = args.data / "nordland-summer-winter-64x32"
    with data_errors(parser):  # the data: a folder missing stops here, before any run
        for folder in (root / "winter", root / "summer"):
            list_traversal(folder)
    table = Table(title=f"--follow on Nordland (map summer, query winter), latency at {args.rate:g} frames/s")
    for column in ("method", "frames/s (folder full)", "latency median ms", "latency 90 % ms"):
        table.add_column(column, justify="right")
    refused: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        os.environ.setdefault("WILOC_CACHE", str(work / "cache"))
        for method in args.methods.split(","):
            try:
                rate = f"{throughput(root / 'winter', root / 'summer', method, work):.0f}"
            except BrokenMeasure as broken:
                rate = "-"
                refused.append(f"{method}: no frames/s: {broken}")
            waits = sorted(latency(root / "winter", root / "summer", method, work, args.rate, args.frames))
            table.add_row(method, rate, f"{1000 * statistics.median(waits):.0f}",
                          f"{1000 * waits[int(0.9 * (len(waits) - 1))]:.0f}")
    console = plain_console()
    console.print(table)
    for line in refused:
        console.print(line)


if __name__ == "__main__":
    main()
