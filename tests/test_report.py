"""`wiloc report`: one self-contained HTML page, checked as text and in a real headless browser
(Debian's chromium; those tests are skipped when it is not installed)."""
from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
from typer.testing import CliRunner

from helpers import places, write_traversal
from wiloc import api
from wiloc.cli import app
from wiloc.labels import threshold_text

runner = CliRunner()
MAX_BYTES = 20_000_000
CHROMIUM = next((found for name in ("chromium", "chromium-browser", "google-chrome") if (found := shutil.which(name))),
                None)
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed "
                                                              "(Debian: apt-get install -y chromium)")


@pytest.fixture
def runs(tmp_path: Path, cache_dir: Path) -> list[Path]:
    """Two methods' results on a generated route whose query runs 5 places past the map's end."""
    scenes = places(45)
    ref = write_traversal(tmp_path / "route" / "ref", scenes[:40], 1.0, 1)
    query = write_traversal(tmp_path / "route" / "query", scenes, 0.7, 2)
    files = []
    for method in ("online", "catgraph"):
        run = api.localize(query, reference=ref, method=method, out=tmp_path / f"query-sad-{method}.csv", jobs=1)
        files.append(run.path)
    return files


def _report(runs: list[Path], out: Path, *options: str) -> Path:
    result = runner.invoke(app, ["report", *map(str, runs), "--gt", "aligned", "-o", str(out), *options])
    assert result.exit_code == 0, result.output
    assert f"wrote {out}" in result.stdout
    return out


def _data(page: str) -> dict:
    """The frame browser's data the page carries."""
    found = re.search(r'<script type="application/json" id="report-data">(.*?)</script>', page, re.DOTALL)
    assert found
    return json.loads(found.group(1))


def test_report_is_one_self_contained_page(runs: list[Path], tmp_path: Path) -> None:
    page = _report(runs, tmp_path / "report.html").read_text(encoding="utf-8")
    assert len(page.encode()) < MAX_BYTES
    assert not re.search(r'(src|href)\s*=\s*["\']?\s*(https?:)?//', page, re.IGNORECASE)  # nothing fetched from a network
    assert "<link" not in page and "@import" not in page and "url(" not in page
    for element in ("run-select", "query-img", "match-img", "truth-img", "prev", "next", "confident-cut"):
        assert f'id="{element}"' in page
    for value in ("wrong", "confident-wrong", "leaving"):
        assert f'value="{value}"' in page
    assert page.count('src="data:image/png;base64,') == 3 + 2  # PR, Figure 5, reliability; per run a timeline
    assert page.count('src="data:image/jpeg;base64,') == 2  # per run the difference matrix
    data = _data(page)
    assert [run["name"].split()[0] for run in data["runs"]] == ["online", "catgraph"]
    online = data["runs"][0]
    assert len(online["frames"]) == 45 and online["has_match"].count(False) == 5  # the 5 places past the map
    assert all(uri.startswith("data:image/jpeg;base64,") for uri in data["images"])
    assert len(data["images"]) == 45 + 40  # each image once, however many runs show it
    assert online["truth"][44] is None and online["truth"][0] is not None
    assert "</script" not in page.split('id="report-data">', 1)[1].split("</script>", 1)[0]


def test_p_new_place_is_drawn_only_for_runs_with_a_frame_without_a_true_match(runs: list[Path],
                                                                               tmp_path: Path) -> None:
    leaving = api.compare(runs, api.TruthSource(kind="aligned")).evaluations  # 5 frames past the map's end
    assert [name.split()[0] for name in api.new_place_series(leaving)] == ["online", "catgraph"]
    every = np.zeros((45, 40), dtype=bool)
    every[np.arange(45), np.minimum(np.arange(45), 39)] = True  # every frame has a true place
    np.save(tmp_path / "every.npy", every)
    inside = api.compare(runs, api.TruthSource(kind="matrix", path=str(tmp_path / "every.npy"))).evaluations
    assert all(e.new_place is not None for e in inside) and api.new_place_series(inside) == {}


def test_the_report_shows_p_new_place_calibration_as_evaluate_gives_it(runs: list[Path], tmp_path: Path) -> None:
    """The page scores every probability it shows: P(new place), drawn in its timelines and
    browser, gets its table (ECE, Brier, mean, share without a true match, cuts) with evaluate's
    numbers; a page of runs that say none notes so."""
    page = _report(runs, tmp_path / "report.html").read_text(encoding="utf-8")
    section = page.split("<h3>P(new place)", 1)[1].split("<h3>", 1)[0]
    rows = re.findall(r"<tr><td>(.*?)</td></tr>", section)
    evaluated = json.loads(runner.invoke(app, ["evaluate", *map(str, runs), "--gt", "aligned", "--json"]).stdout)["runs"]
    assert len(rows) == len(evaluated) == 2
    for row, run in zip(rows, evaluated):
        cells = row.split("</td><td>")
        new = run["new_place"]
        assert cells[:2] == [run["method"], run["traversal"]]
        assert cells[2:6] == [f"{new[key]:.3f}" for key in ("ece", "brier", "mean_confidence", "share_correct")]
        assert cells[8] == str(new["cuts"][0]["accepted"])  # precision, recall, accepted at 0.5
    route = tmp_path / "route"
    plain = api.localize(route / "query", reference=route / "ref", method="threshold",
                         out=tmp_path / "query-sad-threshold.csv", jobs=1).path
    assert "no run says P(new place)" in _report([plain], tmp_path / "plain.html").read_text(encoding="utf-8")


def test_the_report_writes_table_ii_thresholds_as_compare_does(runs: list[Path], tmp_path: Path) -> None:
    """Table II's thresholds carry the digits that say what was chosen (threshold_text), as compare
    prints them: the page gave 3 decimals, so 0.99951 read 1.000."""
    page = _report(runs, tmp_path / "report.html").read_text(encoding="utf-8")
    section = page.split("Table II", 1)[1].split("</table>", 1)[0]
    shown = [row.split("</td><td>")[:3] for row in re.findall(r"<tr><td>(.*?)</td></tr>", section)]
    compared = json.loads(runner.invoke(app, ["compare", *map(str, runs), "--gt", "aligned", "--json"]).stdout)
    chosen = {(row["method"], f"{row['precision']:g}"): row["threshold"] for row in compared["table2"]}
    assert shown and {(method, target) for method, target, _ in shown} == set(chosen)
    assert all(text == threshold_text(chosen[method, target]) for method, target, text in shown), shown


def test_a_report_over_an_existing_file_says_so_and_bad_names_are_refused(runs: list[Path], tmp_path: Path) -> None:
    out = tmp_path / "report.html"
    out.write_text("an older report")
    result = runner.invoke(app, ["report", *map(str, runs), "-o", str(out), "--json"])
    assert result.exit_code == 0 and "replaced the existing file" in result.stderr
    said = json.loads(result.stdout)
    [page] = said["results"]
    assert said["command"] == "report" and page["file"] == str(out) and page["size"] == out.stat().st_size
    assert page["images"] == 85
    assert any("replaced the existing file" in line for line in said["warnings"])
    for bad, exit_code, says in ((tmp_path / "report.txt", 2, "end the name in .html or .htm"),
                                 (tmp_path / "missing" / "report.html", 2, "does not exist")):
        result = runner.invoke(app, ["report", *map(str, runs), "-o", str(bad)])
        assert result.exit_code == exit_code and says in result.stderr and "Traceback" not in result.output
        assert not bad.exists()
    result = runner.invoke(app, ["report", str(tmp_path / "nope.csv"), "-o", str(tmp_path / "r.html")])
    assert result.exit_code == 1 and "nope.csv" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "r.html").exists()


def test_thumbnails_past_the_budget_are_made_again_narrower(runs: list[Path], tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    from wiloc.cache.store import Cache
    from wiloc.figures import report

    comparison = api.compare(runs[:1], api.TruthSource(kind="aligned"))
    wide = report.write_report(comparison, tmp_path / "wide.html", cache=Cache(), thumb_width=96)
    monkeypatch.setattr(report, "THUMB_BUDGET", 1)  # no width fits: the narrowest tried, 48 pixels
    narrow = report.write_report(comparison, tmp_path / "narrow.html", cache=Cache(), thumb_width=96)
    assert (wide.thumb_width, narrow.thumb_width) == (96, 48) and narrow.size < wide.size
    assert narrow.size == (tmp_path / "narrow.html").stat().st_size


def test_a_run_whose_images_are_gone_still_gets_its_page(runs: list[Path], tmp_path: Path) -> None:
    shutil.rmtree(tmp_path / "route" / "query")
    page = _report(runs[:1], tmp_path / "report.html").read_text(encoding="utf-8")
    assert "no images in the frame browser" in page and "no difference matrix" in page
    assert f"{tmp_path / 'route' / 'query'} does not exist" in page  # not "is not an image folder"
    assert f"no difference matrix, its traversal {tmp_path / 'route' / 'query'} does not exist" in page  # which one
    assert _data(page)["images"] == [] and len(_data(page)["runs"][0]["frames"]) == 45
    # the browser filters the confidences the results file holds, not rounded ones
    from wiloc.evaluation.results import read_results
    written = read_results(runs[0]).frames["confidence"].to_numpy(float)
    shown = np.array([np.nan if c is None else c for c in _data(page)["runs"][0]["confidence"]])
    assert np.array_equal(shown, written, equal_nan=True) and np.any(np.round(written, 4) != written)


def _live_run(tmp_path: Path, observed: int, recorded: bool) -> tuple[Path, Path]:
    """A live run over the first ``observed`` frames of a query of 12, saved with its query folder
    (``recorded``) or without: the results file and the query folder."""
    import wiloc

    scenes = places(12)
    ref = write_traversal(tmp_path / "route" / "ref", scenes, 1.0, 1)
    query = write_traversal(tmp_path / "route" / "query", scenes, 0.7, 2)
    loc = wiloc.Localizer(ref, descriptor="sad", method="online", seed=0)
    for k in range(observed):
        loc.observe(query / f"img{k}.png")
    return loc.results(query=query if recorded else None).save(tmp_path / "live-online.csv"), query


def test_a_live_run_over_the_first_frames_of_a_folder_is_drawn(tmp_path: Path, cache_dir: Path) -> None:
    """A live run stopped before the folder's end lists its first frames: they are the run's, where
    the figures said the folder 'no longer gives the frames it lists (... 6 more new)'."""
    from wiloc.cache.store import Cache
    from wiloc.figures.run_figures import matrix_picture

    run, _ = _live_run(tmp_path, 6, recorded=True)
    result = runner.invoke(app, ["evaluate", str(run), "--matrix-plot", str(tmp_path / "matrix.png"),
                                 "--pairs-plot", str(tmp_path / "pairs.png")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "matrix.png").is_file() and (tmp_path / "pairs.png").is_file()
    assert matrix_picture(api.evaluate(run, api.TruthSource()), Cache()).shape == (6, 12)
    page = _report([run], tmp_path / "report.html").read_text(encoding="utf-8")
    assert "no images in the frame browser" not in page and "no difference matrix" not in page
    assert sum(index >= 0 for index in _data(page)["runs"][0]["query_image"]) == 6


def test_a_live_run_saved_without_its_query_shows_no_other_folder(tmp_path: Path, cache_dir: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Localizer.results() without query records none: the figures said the current folder
    ('its query . no longer gives the frames it lists'), having described it in the run's place."""
    run, query = _live_run(tmp_path, 12, recorded=False)
    monkeypatch.chdir(query)  # the images of the run, as it happens: still not a folder the run names
    result = runner.invoke(app, ["evaluate", str(run), "--matrix-plot", str(tmp_path / "matrix.png")])
    assert result.exit_code == 1 and not (tmp_path / "matrix.png").exists()
    assert result.stderr.strip() == (f"error: {run}: the run records no query folder (a live run saved without one: "
                                     "Localizer.results(query=FOLDER) records it), so its images cannot be shown")
    page = _report([run], tmp_path / "report.html").read_text(encoding="utf-8")
    assert page.count("the run records no query folder") == 2  # the browser's note and the matrix's
    assert _data(page)["images"] == []


def _chromium(page: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([CHROMIUM, "--headless", "--disable-gpu", "--no-sandbox", "--hide-scrollbars",
                           "--virtual-time-budget=5000", "--enable-logging=stderr", "--v=0", *args, page.as_uri()],
                          capture_output=True, text=True, timeout=120, check=False)


def assert_loads_without_errors(page: Path) -> str:
    """The page's DOM after its scripts ran: they finished, and no script error or failed load."""
    done = _chromium(page, "--dump-dom")
    assert done.returncode == 0, done.stderr[-2000:]
    dom = done.stdout
    assert 'data-ready="yes"' in dom, "the page's script did not finish"
    assert 'data-errors="yes"' not in dom, re.findall(r'<ul id="page-errors".*?</ul>', dom, re.DOTALL)
    assert ":CONSOLE" not in done.stderr, done.stderr[-2000:]  # the page logs nothing to its console
    return dom


def assert_screenshot_not_blank(page: Path, shot: Path) -> None:
    done = _chromium(page, f"--screenshot={shot}", "--window-size=1280,2400")
    assert done.returncode == 0 and shot.is_file(), done.stderr[-2000:]
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(shot)[..., :3]
    assert image.shape[:2] == (2400, 1280)
    assert float(image.var()) > 0.001  # tables and figures drawn, not a blank canvas
    assert np.mean(np.any(image < 0.9, axis=-1)) > 0.02  # a share of the pixels is not white


@needs_chromium
def test_report_loads_in_headless_chromium_and_its_browser_steps(runs: list[Path], tmp_path: Path) -> None:
    page = _report(runs, tmp_path / "report.html")
    dom = assert_loads_without_errors(page)
    assert re.search(r'<img id="query-img" alt="query" src="data:image/jpeg', dom)
    assert re.search(r'id="counter">1 / 45<', dom)
    assert_screenshot_not_blank(page, tmp_path / "shot.png")
    # the keys step and the filters filter: a script after the page's presses them, then notes what it saw
    steps = page.read_text(encoding="utf-8").replace("</body>", """<script>
var seen = [];
function press(key) { document.dispatchEvent(new KeyboardEvent("keydown", {key: key})); }
press("ArrowRight"); press("ArrowRight"); press("ArrowLeft");
seen.push(document.getElementById("counter").textContent);
document.querySelector("input[value=leaving]").click();
seen.push(document.getElementById("counter").textContent, document.getElementById("frame-info").textContent);
document.getElementById("run-select").value = "1";
document.getElementById("run-select").dispatchEvent(new Event("change"));
document.querySelector("input[value=wrong]").click();
seen.push(document.getElementById("counter").textContent);
document.body.setAttribute("data-seen", JSON.stringify(seen));
</script></body>""")
    stepped = tmp_path / "stepped.html"
    stepped.write_text(steps, encoding="utf-8")
    dom = assert_loads_without_errors(stepped)
    seen = json.loads(re.search(r"data-seen=\"([^\"]*)\"", dom).group(1).replace("&quot;", '"'))
    assert seen[0] == "2 / 45"
    assert seen[1] == "1 / 5" and "no true match in the map" in seen[2]
    catgraph = _data(page.read_text())["runs"][1]
    wrong = [k for k, (right, match) in enumerate(zip(catgraph["correct"], catgraph["match"]))
             if match is not None and not right]
    # a filter keeps to the frame shown (frame 40, the first leaving the map) or the last before it
    assert seen[3] == (f"{max(sum(k <= 40 for k in wrong), 1)} / {len(wrong)}" if wrong else "0 / 0")


@needs_chromium
def test_a_script_error_in_the_page_is_caught(runs: list[Path], tmp_path: Path) -> None:
    """The check above can fail: an error thrown by a script of the page shows in its DOM."""
    page = _report(runs[:1], tmp_path / "report.html")
    broken = tmp_path / "broken.html"
    broken.write_text(page.read_text(encoding="utf-8").replace(
        "</body>", '<script>console.error("boom"); noSuchFunction();</script></body>'))
    done = _chromium(broken, "--dump-dom")
    assert 'data-errors="yes"' in done.stdout and "noSuchFunction" in done.stdout
    assert ':CONSOLE' in done.stderr and '"boom"' in done.stderr  # and the browser's log shows the console


@pytest.mark.realdata
@needs_chromium
def test_gardens_point_report_is_small_and_loads(data_root: Path, tmp_path: Path, cache_dir: Path) -> None:
    walk = data_root / "gardens-point-walking"
    files = [api.localize(walk / "day_left", reference=walk / "day_right", method=method,
                          out=tmp_path / f"day_left-sad-{method}.csv").path for method in ("online", "catgraph")]
    page = _report(files, tmp_path / "report.html")
    assert page.stat().st_size < MAX_BYTES
    text = page.read_text(encoding="utf-8")
    assert not re.search(r'(src|href)\s*=\s*["\']?\s*(https?:)?//', text, re.IGNORECASE)
    assert 200 < len(_data(text)["images"]) <= 400  # every query image, and the map images shown
    assert_loads_without_errors(page)
    assert_screenshot_not_blank(page, tmp_path / "shot.png")


def test_the_page_carries_the_ground_truths_doubts(runs: list[Path], tmp_path: Path) -> None:
    """A page is sent on its own: a ground truth under which no frame has a true match (every
    recall 0) is said on the page, not on the terminal alone."""
    np.save(tmp_path / "none.npy", np.zeros((45, 40), dtype=np.uint8))
    out = tmp_path / "report.html"
    result = runner.invoke(app, ["report", str(runs[0]), "--gt", f"matrix:{tmp_path / 'none.npy'}", "-o", str(out)])
    assert result.exit_code == 0, result.output
    page = out.read_text(encoding="utf-8")
    assert f"{html.escape(str(runs[0]))}: no frame has a true match under this ground truth" in page
    assert result.stderr.count("no frame has a true match") == 1  # said once on the terminal too
