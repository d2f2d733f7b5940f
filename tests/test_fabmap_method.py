"""FAB-MAP and local-feature CAT-Graph as methods: bag-of-words descriptors, evidence rows, the
batch and the streaming paths, and the command line."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from wiloc import api
from wiloc.cache.store import Cache
from wiloc.cli import app
from wiloc.errors import UsageError
from wiloc.evaluation.truth_source import TruthSource
from wiloc.localization.localizer import Localizer

SMALL = {"feature": "orb", "words": 128, "max_features": 200, "iterations": 8}
FRAMES, STEP, WIDTH = 60, 16, 320


@dataclass(frozen=True)
class Route:
    reference: Path
    query: Path
    training: Path


def _street(rng: np.random.Generator, height: int = 240) -> np.ndarray:
    """A strip of random discs and boxes: plenty of corners and blobs for local features."""
    image = np.full((height, WIDTH + FRAMES * STEP), 128, np.uint8)
    for _ in range(image.shape[1] // 3):
        x, y, grey = int(rng.integers(0, image.shape[1])), int(rng.integers(0, height)), int(rng.integers(0, 256))
        if rng.random() < 0.5:
            cv2.circle(image, (x, y), int(rng.integers(3, 14)), grey, -1)
        else:
            cv2.rectangle(image, (x, y), (x + int(rng.integers(4, 24)), y + int(rng.integers(4, 24))), grey, -1)
    return image


def _drive(street: np.ndarray, folder: Path, rng: np.random.Generator, gain: float, noise: float,
           shift: int) -> Path:
    """Frames along the strip, one place per frame (frame k of every drive is the same place)."""
    folder.mkdir(parents=True)
    for k in range(FRAMES):
        window = street[:, k * STEP + shift:k * STEP + shift + WIDTH].astype(np.float64)
        frame = window * gain + rng.normal(0.0, noise, window.shape)
        cv2.imwrite(str(folder / f"f{k:03d}.png"), np.clip(frame, 0, 255).astype(np.uint8))
    return folder


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> tuple[Route, Cache, dict]:
    """A street driven twice (map, darker noisier query), another street for the vocabulary."""
    root = tmp_path_factory.mktemp("fabmap")
    rng = np.random.default_rng(0)
    street, elsewhere = _street(rng), _street(rng)
    route = Route(_drive(street, root / "map", rng, 1.0, 3.0, 0), _drive(street, root / "query", rng, 0.8, 8.0, 3),
                  _drive(elsewhere, root / "training", rng, 1.0, 3.0, 0))
    cache = Cache(root / "cache")
    report = api.vocabulary([route.training], SMALL, cache=cache)
    return route, cache, {"file": str(report.path)}


def _rows(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, comment="#", dtype=str, keep_default_na=False)


@pytest.mark.parametrize("method, least", [("fabmap", 0.3), ("catgraph", 0.85)])
def test_bow_methods_read_fabmap_evidence_and_stream_as_they_batch(setup, method: str, least: float,
                                                                   tmp_path: Path) -> None:
    route, cache, bow = setup
    query = route.query
    run = api.localize(query, reference=route.reference, descriptor="bow", descriptor_params=bow, method=method,
                       out=tmp_path / "batch.csv", cache=cache)
    assert run.results.header.rows == "fabmap" and "new_place" in run.results.frames.columns
    assert run.results.header.fabmap_training == (str(route.training.resolve()),)
    evaluation = api.evaluate(run, TruthSource(tolerance=2))
    assert evaluation.summary.as_dict()["recall_at_1"] >= least  # chance: 5 / 60
    loc = Localizer(route.reference, descriptor="bow", descriptor_params=bow, method=method, cache=cache)
    streamed = [loc.observe(path) for path in sorted(query.iterdir())]
    batch = _rows(run.path)
    assert batch["match"].tolist() == [d.match_name for d in streamed]
    assert batch["confidence"].tolist() == [f"{d.confidence:.9g}" for d in streamed]


def test_fabmap_closes_loops_in_sequence_mode(setup, tmp_path: Path) -> None:
    route, cache, bow = setup
    loop = tmp_path / "loop"
    loop.mkdir()
    frames = sorted(route.reference.iterdir()) + sorted(route.query.iterdir())[:30]  # the first 30 places again
    for i, path in enumerate(frames):
        (loop / f"g{i:03d}{path.suffix}").write_bytes(path.read_bytes())
    run = api.localize(loop, descriptor="bow", descriptor_params=bow, method="fabmap", cache=cache)
    second = run.decisions.match[FRAMES:]
    assert np.mean(np.abs(second - np.arange(30)) <= 2) > 0.3
    new_place = run.decisions.columns["new_place"]
    assert np.nanmedian(new_place[15:FRAMES]) > np.nanmedian(new_place[FRAMES:])


def test_fabmap_needs_bag_of_words(setup) -> None:
    route, cache, _ = setup
    with pytest.raises(UsageError) as err:
        api.localize(route.query, reference=route.reference, method="fabmap", cache=cache)
    assert err.value.parameter == "descriptor"


def test_the_command_line_builds_a_vocabulary_and_runs_fabmap(setup, tmp_path: Path) -> None:
    route, cache, _ = setup
    runner = CliRunner()
    built = runner.invoke(app, ["vocabulary", str(route.training), "--feature", "orb", "--words", "128",
                                "--max-features", "200", "--iterations", "8", "--cache", str(cache.root), "--json"])
    assert built.exit_code == 0, built.output
    key = json.loads(built.stdout)["results"][0]["key"]
    assert json.loads(built.stdout)["results"][0]["built"] is False  # the fixture built the same one
    out = tmp_path / "r.csv"
    done = runner.invoke(app, ["localize", str(route.query), "--map", str(route.reference), "--descriptor", "bow",
                               "--vocabulary", key, "--method", "fabmap", "--cache", str(cache.root), "--out", str(out)])
    assert done.exit_code == 0, done.output
    assert len(_rows(out)) == FRAMES
    wrong = runner.invoke(app, ["localize", str(route.query), "--map", str(route.reference), "--vocabulary", key])
    assert wrong.exit_code == 2 and "--vocabulary: applies to --descriptor bow only" in wrong.stderr
    missing = runner.invoke(app, ["localize", str(route.query), "--map", str(route.reference), "--descriptor",
                                  "bow", "--vocabulary", "nope", "--cache", str(cache.root)])
    assert missing.exit_code == 2 and "--vocabulary: 'nope' is neither a vocabulary file" in missing.stderr


def test_fabmap_s_own_parameters_reach_its_model_from_the_api_and_the_command_line(setup, tmp_path: Path) -> None:
    route, cache, bow = setup
    runs = {name: api.localize(route.query, reference=route.reference, descriptor="bow", descriptor_params=bow,
                               method="fabmap", method_params={"new_place": name}, cache=cache,
                               out=tmp_path / f"{name}.csv") for name in ("sampled", "mean-field")}
    assert runs["mean-field"].results.header.params["new_place"] == "mean-field"
    new_place = {name: run.decisions.columns["new_place"] for name, run in runs.items()}
    assert not np.allclose(new_place["sampled"], new_place["mean-field"])  # the model's new place changed
    loc = Localizer(route.reference, descriptor="bow", descriptor_params=bow, method="fabmap", new_place="mean-field",
                    cache=cache)
    first = loc.observe(min(route.query.iterdir()))
    assert f"{first.new_place:.9g}" == f"{new_place['mean-field'][0]:.9g}"
    runner = CliRunner()
    args = ["localize", str(route.query), "--map", str(route.reference), "--descriptor", "bow", "--vocabulary",
            bow["file"], "--cache", str(cache.root), "--new-place", "mean-field"]
    done = runner.invoke(app, [*args, "--method", "fabmap", "--out", str(tmp_path / "cli.csv")])
    assert done.exit_code == 0, done.output
    assert _rows(tmp_path / "cli.csv")["new_place"].tolist() == _rows(runs["mean-field"].path)["new_place"].tolist()
    refused = runner.invoke(app, [*args, "--method", "catgraph"])
    assert refused.exit_code == 2 and "--new-place: method 'catgraph' takes no such option" in refused.stderr


def _evidence(rng: np.random.Generator, frames: int = 80, n_map: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """FAB-MAP-like evidence rows in hundreds of nats, highest around the true place (query frame
    k at map place k + 20) among look-alikes, and the true places."""
    truth = np.arange(frames) + 20
    offset = truth[:, None] - np.arange(n_map)[None, :]
    return 200.0 * (rng.standard_normal((frames, n_map)) + 2.5 * np.exp(-0.5 * (offset / 1.5) ** 2)), truth


def test_catgraph_ranks_fabmap_evidence_so_its_scale_does_not_count() -> None:
    from wiloc.methods.base import MapContext
    from wiloc.methods.registry import make_method
    rows, truth = _evidence(np.random.default_rng(5))
    steps = np.ones(rows.shape[1] - 1)
    runs = []
    for scale in (1.0, 100.0):  # hundreds of nats, then tens of thousands
        method = make_method("catgraph", {"particles": 500})
        method.start(MapContext(sequence=False, exclude_recent=0, n_map=rows.shape[1], rows="log_ratio",
                                neighbours=lambda: steps))
        runs.append([method.step(scale * row) for row in rows])
    one, hundred = runs
    assert [d.match for d in one] == [d.match for d in hundred]
    np.testing.assert_allclose([d.confidence for d in one], [d.confidence for d in hundred], rtol=1e-9)
    np.testing.assert_allclose([100 * d.difference for d in one], [d.difference for d in hundred], rtol=1e-12)
    confidence = np.array([d.confidence for d in one])
    right = np.abs(np.array([d.match for d in one]) - truth) <= 2
    assert not np.any(confidence[~right] >= 0.99)  # a probability, not FAB-MAP's certainty
    assert abs(confidence.mean() - right.mean()) <= 0.1


def test_fabmap_and_catgraph_write_minus_the_evidence_as_the_difference(setup) -> None:
    route, cache, bow = setup
    runs = {method: api.localize(route.query, reference=route.reference, descriptor="bow", descriptor_params=bow,
                                 method=method, cache=cache).decisions for method in ("fabmap", "catgraph")}
    fabmap, catgraph = runs["fabmap"], runs["catgraph"]
    same = fabmap.match == catgraph.match  # fabmap is right on a third of the frames here
    assert same.sum() >= 5
    np.testing.assert_array_equal(fabmap.difference[same], catgraph.difference[same])
    assert np.median(fabmap.difference) < 0 and np.median(catgraph.difference) < 0  # -r: low = alike


def _thumbnails(folder: Path, frames: int) -> Path:
    """64 x 48 images (the route's shape) of a few discs each: a handful of local features per
    image, some none."""
    folder.mkdir()
    rng = np.random.default_rng(1)
    for k in range(frames):
        image = np.full((48, 64), 128, np.uint8)
        for _ in range(6):
            cv2.circle(image, (int(rng.integers(0, 64)), int(rng.integers(0, 48))), int(rng.integers(2, 6)),
                       int(rng.integers(0, 256)), -1)
        cv2.imwrite(str(folder / f"t{k:03d}.png"), image)
    return folder


def test_a_vocabulary_of_images_too_small_for_local_features_is_warned_of(setup, tmp_path: Path) -> None:
    route, cache, good = setup
    tiny = _thumbnails(tmp_path / "tiny", 30)
    runner = CliRunner()
    built = runner.invoke(app, ["vocabulary", str(tiny), "--words", "16", "--cache", str(cache.root), "--json"])
    assert built.exit_code == 0, built.output
    report = json.loads(built.stdout)
    [warning] = report["warnings"]
    assert warning.startswith(f"warning: vocabulary {report['results'][0]['key']}: its 30 training images give a median of ")
    assert warning in built.stderr.replace("warning ", "warning: ", 1)
    done = runner.invoke(app, ["localize", str(route.query), "--map", str(route.reference), "--descriptor", "bow",
                               "--vocabulary", report["results"][0]["key"], "--method", "fabmap", "--cache", str(cache.root),
                               "--out", str(tmp_path / "r.csv"), "--json"])
    assert done.exit_code == 0, done.output
    assert json.loads(done.stdout)["warnings"] == [warning]
    run = api.localize(route.query, reference=route.reference, descriptor="bow", descriptor_params=good,
                       method="fabmap", cache=cache)
    assert run.warnings == []  # 320 x 240 images: plenty of words


def test_a_query_or_map_of_images_too_small_for_local_features_is_warned_of(setup, tmp_path: Path) -> None:
    """A vocabulary that passes, a query (then a map, then a map followed) of thumbnails: one line
    on stderr naming it."""
    route, cache, good = setup
    tiny = _thumbnails(tmp_path / "tiny", 30)
    done = CliRunner().invoke(app, ["localize", str(tiny), "--map", str(route.reference), "--descriptor", "bow",
                                    "--vocabulary", good["file"], "--method", "fabmap", "--cache", str(cache.root),
                                    "--out", str(tmp_path / "r.csv"), "--json"])
    assert done.exit_code == 0, done.output
    [warning] = json.loads(done.stdout)["warnings"]
    assert warning.startswith(f"warning: query {tiny.resolve()}: its 30 images give a median of ")
    assert warning.endswith("so their bag-of-words matching and FAB-MAP's evidence degenerate")
    said = [line for line in done.stderr.splitlines() if line.startswith("warning")]
    assert said == [warning.replace("warning: ", "warning ", 1)]
    run = api.localize(route.query, reference=tiny, descriptor="bow", descriptor_params=good, method="catgraph",
                       method_params={"particles": 200}, cache=cache)
    [warning] = run.warnings
    assert warning.startswith(f"map {tiny.resolve()}: its 30 images give a median of ")
    followed = CliRunner().invoke(app, ["localize", str(route.query), "--map", str(tiny), "--descriptor", "bow",
                                        "--vocabulary", good["file"], "--method", "fabmap", "--cache", str(cache.root),
                                        "--out", str(tmp_path / "f.csv"), "--follow", "--idle", "0.5", "--json"])
    assert followed.exit_code == 0, followed.output
    lines = followed.stdout.splitlines()
    assert json.loads(lines[0]) == {"warnings": [f"warning: {warning}"]}  # said before the first frame
    assert len(lines) == 1 + 60
    assert followed.stderr.count(warning) == 1


@pytest.mark.realdata
@pytest.mark.slow
def test_catgraph_on_fabmap_evidence_is_calibrated_on_gardens_point(data_root: Path,
                                                                    real_data_cache: Path) -> None:
    """The acceptance of a probability: vocabulary from night_right, day_left against day_right
    (the vocabulary and descriptors examples/table1.py makes too: the cache it shares with it)."""
    gp = data_root / "gardens-point-walking"
    cache = Cache(real_data_cache)
    report = api.vocabulary([gp / "night_right"], cache=cache)
    assert report.vocabulary.too_few_words() is None
    run = api.localize(gp / "day_left", reference=gp / "day_right", descriptor="bow",
                       descriptor_params={"file": str(report.path)}, method="catgraph", cache=cache)
    assert run.warnings == []
    e = api.evaluate(run, TruthSource(tolerance=2))
    assert e.calibration.ece <= 0.10
    assert not np.any(e.confidence[~e.correct] >= 0.99)  # measured: ECE 0.032, 181 frames at 0.99+, none wrong
    assert e.summary.as_dict()["recall_at_1"] >= 0.95


@pytest.mark.realdata
@pytest.mark.slow
def test_catgraph_with_a_vocabulary_of_thumbnails_is_warned_of_and_stays_a_probability(
        data_root: Path, real_data_cache: Path) -> None:
    """A vocabulary of Nordland's 64 x 32 thumbnails (FAB-MAP's log-ratios of hundreds of nats):
    warned of where it is built and where it is used; catgraph's confidence still a probability.
    (The shared cache: Gardens Point's local features are those the examples' vocabularies keep.)"""
    gp = data_root / "gardens-point-walking"
    cache = Cache(real_data_cache)
    report = api.vocabulary([data_root / "nordland-summer-winter-64x32" / "summer"], cache=cache)
    sparse = report.vocabulary.too_few_words()
    assert sparse is not None
    run = api.localize(gp / "day_left", reference=gp / "day_right", descriptor="bow",
                       descriptor_params={"file": str(report.path)}, method="catgraph", cache=cache)
    assert run.warnings == [sparse]
    e = api.evaluate(run, TruthSource(tolerance=2))
    assert e.calibration.ece <= 0.10
    assert not np.any(e.confidence[~e.correct] >= 0.99)  # measured: ECE 0.041, 129 frames at 0.99+, none wrong
    assert e.summary.as_dict()["recall_at_1"] >= 0.8
