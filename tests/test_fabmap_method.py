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
from wiloc.cache import Cache
from wiloc.cli import app
from wiloc.errors import UsageError
from wiloc.groundtruth import TruthSource
from wiloc.localizer import Localizer

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
    assert run.results.meta["rows"] == "fabmap" and "new_place" in run.results.frames.columns
    assert run.results.meta["fabmap_training"] == [str(route.training.resolve())]
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
    key = json.loads(built.stdout)["key"]
    assert json.loads(built.stdout)["built"] is False  # the fixture built the same one
    out = tmp_path / "r.csv"
    done = runner.invoke(app, ["localize", str(route.query), "--map", str(route.reference), "--descriptor", "bow",
                               "--vocabulary", key, "--method", "fabmap", "--cache", str(cache.root), "--out", str(out)])
    assert done.exit_code == 0, done.output
    assert len(_rows(out)) == FRAMES
    wrong = runner.invoke(app, ["localize", str(route.query), "--map", str(route.reference), "--vocabulary", key])
    assert wrong.exit_code == 2 and "--vocabulary: applies to --descriptor bow only" in wrong.stderr
    missing = runner.invoke(app, ["localize", str(route.query), "--map", str(route.reference), "--descriptor",
                                  "bow", "--vocabulary", "nope", "--cache", str(cache.root)])
    assert missing.exit_code == 1 and "--vocabulary: 'nope' is neither a vocabulary file" in missing.stderr
