"""examples/live.py on the real data: a Gardens Point walk played frame by frame through a
``Localizer``, restarted halfway from its saved state, scored as the batch run is.

What it prints must hold together: the resumed run decides every frame as an uninterrupted one;
with the frames as the cache decodes them (``--frames read``, the default) the live run's rows
and metrics are the batch run's, and its R@1 is what docs/results.md quotes for catgraph on
day_left, within one frame (the tolerance tests/test_examples.py allows another CPU); the results
file it wrote scores as printed. With full-size BGR arrays (``--frames bgr``, a camera driver's)
only the restart is checked: such frames are described otherwise than the files. No data, an
``--out`` that is a file, a reader of the live log that goes (``| head``) and Ctrl-C each end it
with one line (or none) and the documented exit code, never a traceback.
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import interrupt_after_six_frames

from wiloc import api
from wiloc.cache.store import Cache
from wiloc.errors import EXIT_CLOSED_OUTPUT, EXIT_INTERRUPTED

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "live.py"
ONE_FRAME = 1 / 200  # of Gardens Point's 200: how far another CPU may move R@1 (tests/test_examples.py)
AGREEMENT = re.compile(r"^live run against (an uninterrupted one|a batch .*?): (\d+) of (\d+) frames decided alike",
                       re.MULTILINE)


def _run(data_root: Path, cache: Path, out: Path, *options: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "WILOC_CACHE": str(cache)}
    return subprocess.run([sys.executable, str(EXAMPLE), str(data_root), "--out", str(out), "--quiet", *options],
                          capture_output=True, text=True, env=env, check=False)


def _agreements(stdout: str) -> dict[str, tuple[int, int]]:
    """'uninterrupted' and 'batch': (frames alike, frames), as printed."""
    found = {("uninterrupted" if "uninterrupted" in what else "batch"): (int(alike), int(frames))
             for what, alike, frames in AGREEMENT.findall(stdout)}
    assert set(found) == {"uninterrupted", "batch"}, stdout
    return found


def _metrics_table(stdout: str) -> dict[str, tuple[str, str, str]]:
    """The printed table: metric -> (live, batch, equal)."""
    rows = [line.strip("|").split("|") for line in stdout.splitlines() if line.startswith("| ")]
    return {cells[0].strip(): tuple(c.strip() for c in cells[1:]) for cells in rows[1:]}


def _quoted_r_at_1() -> float:
    """catgraph's R@1 on day_left as docs/results.md quotes it from examples/gardens_point.py."""
    text = (REPO / "docs" / "results.md").read_text(encoding="utf-8")
    block = text[text.index("<!-- begin gardens_point"):text.index("<!-- end gardens_point")]
    lines = [line.strip("|").split("|") for line in block.splitlines() if line.startswith("|")]
    header = [cell.strip() for cell in lines[0]]
    row = next(cells for cells in lines if [c.strip() for c in cells[:2]] == ["catgraph", "day_left"])
    return float(row[header.index("R@1")]) / 100


@pytest.mark.realdata
@pytest.mark.slow  # two Localizer passes and a batch run over a Gardens Point walk: seconds, more on a cold cache
def test_live_run_resumes_and_scores_as_the_batch_run(data_root: Path, real_data_cache: Path, tmp_path: Path) -> None:
    proc = _run(data_root, real_data_cache, tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    assert not re.search(r"^Image\d+\.jpg ", proc.stdout, re.MULTILINE)  # --quiet: no line per frame
    frames = len(list((data_root / "gardens-point-walking" / "day_left").glob("*.jpg")))
    agreements = _agreements(proc.stdout)
    assert agreements["uninterrupted"] == (frames, frames)
    assert agreements["batch"] == (frames, frames)
    assert re.search(r"^restart after frame 100: saved .*state\.npz", proc.stdout, re.MULTILINE)

    table = _metrics_table(proc.stdout)
    assert set(table) == {"R@1", "AP", "ECE", "precision@0.9", "recall@0.9"}
    for metric, (live, batch, equal) in table.items():
        assert live == batch and equal == "yes", (metric, live, batch)
    assert "live metrics equal the batch run's" in proc.stdout
    summary = json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    assert summary["live"] == summary["batch"]
    assert summary["live"]["R@1"] >= _quoted_r_at_1() - ONE_FRAME
    assert float(table["R@1"][0]) == pytest.approx(summary["live"]["R@1"], abs=5e-5)

    written = api.evaluate(tmp_path / "day_left-sad-catgraph.csv", api.TruthSource(kind="aligned", tolerance=2))
    assert written.summary.as_dict()["recall_at_1"] == summary["live"]["R@1"]
    assert written.calibration.ece == pytest.approx(summary["live"]["ECE"], rel=1e-6)  # the file keeps 9 digits
    cpu = summary["cpu_ms"]["observe"]
    assert 0 < cpu["median_ms"] <= cpu["p95_ms"] <= cpu["max_ms"]
    assert re.search(r"^CPU per frame: observe median [\d.]+ ms, 95th percentile [\d.]+ ms", proc.stdout, re.MULTILINE)


@pytest.mark.realdata
@pytest.mark.slow
def test_camera_frames_resume_as_an_uninterrupted_run(data_root: Path, real_data_cache: Path,
                                                      tmp_path: Path) -> None:
    proc = _run(data_root, real_data_cache, tmp_path, "--frames", "bgr")
    assert proc.returncode == 0, proc.stderr[-2000:]
    frames = len(list((data_root / "gardens-point-walking" / "day_left").glob("*.jpg")))
    agreements = _agreements(proc.stdout)
    assert agreements["uninterrupted"] == (frames, frames)
    if agreements["batch"][0] < frames:
        assert "(not checked: full-size BGR arrays give other descriptors" in proc.stdout
    assert json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))["batch_checked"] is False


def test_missing_data_is_one_error_line(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, str(EXAMPLE), str(tmp_path), "--out", str(tmp_path / "out"), "--quiet"],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        f"error: {tmp_path / 'gardens-point-walking' / 'day_right'}: dataset folder not found "
        "(pass the data folder or set WILOC_DATA)"]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("options", "said"), [
    (["--bogus"], "error: --bogus: no such option of live.py (see --help)"),
    (["--seed", "x"], "error: --seed: invalid int value: 'x'")])
def test_a_bad_option_is_one_line_naming_it(tmp_path: Path, options: list[str], said: str) -> None:
    """As the other examples (examples/protocol.py): one line and exit code 2, not argparse's usage lines."""
    proc = subprocess.run([sys.executable, str(EXAMPLE), str(tmp_path), "--out", str(tmp_path / "out"), *options],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == [said]
    assert not (tmp_path / "out").exists()


@pytest.mark.realdata
def test_out_that_is_a_file_is_one_error_line_before_any_work(data_root: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.write_text("not a folder\n", encoding="utf-8")
    proc = _run(data_root, tmp_path / "cache", out)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [f"error: {out}: not a folder (--out names the output folder)"]
    assert proc.stdout == ""
    assert out.read_text(encoding="utf-8") == "not a folder\n"


def _started(data_root: Path, cache: Path, out: Path) -> subprocess.Popen[str]:
    """The example running with its live log on a pipe, Ctrl-C reaching it; its first decision read."""
    env = {**os.environ, "WILOC_CACHE": str(cache)}
    proc = subprocess.Popen([sys.executable, str(EXAMPLE), str(data_root), "--out", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # noqa: PLW1509 - takes no lock
    assert proc.stdout is not None
    for line in proc.stdout:
        if line.startswith("Image000.jpg"):
            return proc
    raise AssertionError(proc.stderr.read() if proc.stderr else "no decision printed")


@pytest.mark.realdata
def test_reader_gone_or_ctrl_c_is_no_traceback(data_root: Path, real_data_cache: Path, tmp_path: Path) -> None:
    proc = _started(data_root, real_data_cache, tmp_path / "piped")
    proc.stdout.close()  # | head: the reader has gone
    assert proc.wait() == EXIT_CLOSED_OUTPUT
    assert proc.stderr.read() == ""
    proc = _started(data_root, real_data_cache, tmp_path / "stopped")
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate()
    assert proc.returncode == EXIT_INTERRUPTED
    assert stderr == "error: interrupted\n"


@pytest.mark.realdata
@pytest.mark.parametrize("example", ["gardens_point", "nordland", "table1", "loop_closure"])
def test_every_example_takes_an_out_that_is_a_file_as_one_error_line(data_root: Path, tmp_path: Path,
                                                                      example: str) -> None:
    """The examples share their output folder's check (protocol.py): a file named by ``--out`` is
    one error line before any work, and is left as it was."""
    out = tmp_path / "out"
    out.write_text("not a folder\n", encoding="utf-8")
    proc = subprocess.run([sys.executable, str(EXAMPLE.parent / f"{example}.py"), str(data_root), "--out", str(out)],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [f"error: {out}: not a folder (--out names the output folder)"]
    assert out.read_text(encoding="utf-8") == "not a folder\n"


#: Runs an example script as ``python SCRIPT ARGS...`` does, from ``python -c`` (its folder first on
#: sys.path: it imports protocol.py beside it).
_RUN_SCRIPT = ("import runpy, sys; from pathlib import Path; sys.argv = sys.argv[1:]; "
               "sys.path.insert(0, str(Path(sys.argv[0]).parent)); runpy.run_path(sys.argv[0], run_name='__main__')")


@pytest.mark.realdata
def test_an_example_ends_on_ctrl_c_with_one_line(data_root: Path, cache_dir: Path, tmp_path: Path) -> None:
    """Ctrl-C while gardens_point.py describes is 'error: interrupted' and exit code 130, as
    live.py and the wiloc command end; it was a KeyboardInterrupt's traceback. (The one-table
    scripts end the same way: tests/test_examples.py.)"""
    script = EXAMPLE.parent / "gardens_point.py"
    run = interrupt_after_six_frames([_RUN_SCRIPT, str(script), str(data_root), "--out", str(tmp_path / "out")],
                                     Cache(cache_dir), signal.SIGINT)
    stderr = run.stderr.read().decode()
    assert run.returncode == EXIT_INTERRUPTED, stderr
    assert stderr.strip().splitlines()[-1] == "error: interrupted" and "Traceback" not in stderr, stderr

