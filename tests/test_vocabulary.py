"""Local features, clustering, the visual vocabulary and its cache file, the bow descriptor."""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import cv2
import h5py
import numpy as np
import pytest
from numpy.typing import NDArray

from wiloc.bow.clustering import assign, kmajority, kmeans
from wiloc.bow.features import extract_features, to_scale
from wiloc.bow.vocabulary import Vocabulary, pack_words, read_vocabulary, train_vocabulary, unpack_words
from wiloc.bow.vocabulary_params import VocabularyParams
from wiloc.cache.entries import Entry
from wiloc.cache.features import FeatureStore
from wiloc.cache.store import Cache
from wiloc.description.describing import DescribeReport, describe_folder
from wiloc.description.vocabulary_build import build_vocabulary, vocabulary_path
from wiloc.descriptors import get_descriptor
from wiloc.descriptors.base import DescriptorSpec
from wiloc.errors import ParameterError, WilocError
from wiloc.sources.frames import fingerprint

REPO = Path(__file__).resolve().parents[1]
SMALL = VocabularyParams(words=16, max_features=60, max_side=320, iterations=10)


def _scene(seed: int, h: int = 180, w: int = 240) -> np.ndarray:
    """A textured image with blobs and rectangles: plenty of corners and blobs."""
    rng = np.random.default_rng(seed)
    image = cv2.GaussianBlur(rng.integers(0, 256, (h, w), dtype=np.uint8), (0, 0), 3)
    for _ in range(12):
        x, y = int(rng.integers(10, w - 40)), int(rng.integers(10, h - 40))
        cv2.rectangle(image, (x, y), (x + int(rng.integers(8, 30)), y + int(rng.integers(8, 30))),
                      int(rng.integers(0, 256)), -1)
        cv2.circle(image, (int(rng.integers(0, w)), int(rng.integers(0, h))),
                   int(rng.integers(3, 12)), int(rng.integers(0, 256)), -1)
    return image


def _folder(path: Path, seeds: range) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    for i, seed in enumerate(seeds):
        cv2.imwrite(str(path / f"img{i}.png"), _scene(seed))
    return path


# ----------------------------------------------------------------------------- features

@pytest.mark.parametrize(("feature", "width", "dtype"), [("sift", 128, np.float32), ("orb", 32, np.uint8)])
def test_features_are_capped_typed_and_empty_on_a_flat_image(feature: str, width: int, dtype: type) -> None:
    image = _scene(0, 360, 480)
    many = extract_features(image, feature, max_features=500)
    few = extract_features(image, feature, max_features=25)
    assert many.dtype == dtype and many.shape[1] == width and len(many) > 25
    assert few.shape == (25, width)
    flat = extract_features(np.full((100, 100), 128, np.uint8), feature)
    assert flat.shape == (0, width) and flat.dtype == dtype


def test_images_are_shrunk_to_max_side_never_enlarged() -> None:
    assert to_scale(np.zeros((540, 960), np.uint8), 640).shape == (360, 640)
    assert to_scale(np.zeros((960, 540), np.uint8), 640).shape == (640, 360)
    assert to_scale(np.zeros((100, 200), np.uint8), 640).shape == (100, 200)


# ----------------------------------------------------------------------------- clustering

def test_assign_matches_brute_force_for_both_metrics() -> None:
    rng = np.random.default_rng(0)
    x, c = rng.normal(size=(300, 16)).astype(np.float32), rng.normal(size=(20, 16)).astype(np.float32)
    brute = np.argmin(((x[:, None] - c[None]) ** 2).sum(-1), axis=1)
    assert np.array_equal(assign(x, c), brute)
    b, cb = rng.integers(0, 256, (300, 32), dtype=np.uint8), rng.integers(0, 256, (20, 32), dtype=np.uint8)
    hamming = np.unpackbits(b[:, None] ^ cb[None], axis=-1).sum(-1)
    assert np.array_equal(hamming[np.arange(300), assign(b, cb)], hamming.min(axis=1))
    with pytest.raises(ValueError, match="do not match"):
        assign(x, cb)


def test_kmeans_finds_separated_clusters_and_stops_when_stable() -> None:
    rng = np.random.default_rng(1)
    truth = rng.normal(scale=20, size=(4, 8)).astype(np.float32)
    x = (truth[rng.integers(0, 4, 2000)] + rng.normal(size=(2000, 8))).astype(np.float32)
    rounds: list[int] = []
    centres = kmeans(x, 4, 50, seed=0, step=rounds.append)
    nearest = np.min(((centres[:, None] - truth[None]) ** 2).sum(-1), axis=0)
    assert np.all(np.sqrt(nearest) < 0.3)
    assert rounds == list(range(1, len(rounds) + 1)) and len(rounds) < 50


def test_kmajority_recovers_binary_prototypes() -> None:
    rng = np.random.default_rng(2)
    prototypes = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    bits = np.unpackbits(prototypes[rng.integers(0, 5, 3000)], axis=1)
    noisy = np.packbits(bits ^ (rng.random(bits.shape) < 0.1), axis=1)  # 10 % of bits flipped
    rounds: list[int] = []
    centres = kmajority(noisy, 5, 30, seed=0, step=rounds.append)
    distance = np.unpackbits(centres[:, None] ^ prototypes[None], axis=-1).sum(-1)
    assert np.all(distance.min(axis=0) == 0)  # every prototype found exactly
    assert len(rounds) < 30


@pytest.mark.parametrize("dtype", [np.float32, np.uint8])
def test_repeated_features_start_no_two_words_alike(dtype: type) -> None:
    """Features repeated (an image given twice) were drawn as two initial centres alike: the
    second never won a feature, so a vocabulary of 12 words held fewer distinct ones; and the
    words were made from fewer distinct features than words, with no word said."""
    distinct = np.random.default_rng(2).integers(0, 256, (12, 32)).astype(dtype)
    repeated = np.concatenate([distinct] * 5)
    cluster = kmeans if dtype == np.float32 else kmajority
    assert len(np.unique(cluster(repeated, 12, 5, seed=0), axis=0)) == 12
    with pytest.raises(ValueError, match="12 distinct features cannot make 13 clusters"):
        cluster(repeated, 13, 5, seed=0)
    params = VocabularyParams.create({"words": 13, "feature": "sift" if dtype == np.float32 else "orb"})
    with pytest.raises(ParameterError, match=r"13 words need at least as many distinct training features; the "
                                             r"training images gave 60 \(12 distinct\)"):
        train_vocabulary("key", params, ["a.png"] * 5, [distinct] * 5)


def test_too_few_features_for_the_words() -> None:
    with pytest.raises(ValueError, match="cannot make"):
        kmeans(np.zeros((3, 4), np.float32), 4, 5, seed=0)


# ----------------------------------------------------------------------------- vocabulary

@pytest.mark.parametrize(("name", "value"), [
    ("feature", "surf"), ("words", 1), ("max_features", 0), ("max_side", 8), ("iterations", 0),
    ("seed", -1), ("words", 2.0), ("words", True),
])
def test_vocabulary_parameters_are_checked_and_named(name: str, value: object) -> None:
    with pytest.raises(ParameterError) as info:
        VocabularyParams(**{name: value})
    assert info.value.parameter == name


def test_word_presence_packs_and_unpacks() -> None:
    present = np.random.default_rng(0).random((3, 21)) < 0.5
    packed = pack_words(present)
    assert packed.shape == (3, 3) and packed.dtype == np.uint8
    assert np.array_equal(unpack_words(packed, 21), present)


def test_vocabulary_round_trips_through_the_cache(tmp_path: Path, cache_dir: Path) -> None:
    folder = _folder(tmp_path / "train", range(6))
    cache = Cache(cache_dir)
    calls: list[tuple[int, int]] = []
    report = build_vocabulary([folder], cache, SMALL, progress=lambda d, t: calls.append((d, t)))
    vocabulary = report.vocabulary
    assert report.built and report.path == cache_dir / "vocabularies" / f"{vocabulary.key}.h5"
    assert report.path == vocabulary_path(cache, vocabulary.key)
    assert vocabulary.centres.shape == (16, 128) and vocabulary.training_occurrences.shape == (6, 16)
    assert calls[-1] == (6 + SMALL.iterations, 6 + SMALL.iterations)
    assert [d for d, _ in calls] == sorted(d for d, _ in calls)
    stored = read_vocabulary(report.path)
    assert stored.key == vocabulary.key and stored.params == SMALL
    assert np.array_equal(stored.centres, vocabulary.centres)
    assert np.array_equal(stored.training_occurrences, vocabulary.training_occurrences)
    assert stored.training_frames == tuple(str((folder / f"img{i}.png").resolve()) for i in range(6))
    with h5py.File(report.path, "r") as f:
        assert f.attrs["features"] == report.features > 16
    # Again: read, not built; the same images elsewhere: the same key.
    again = build_vocabulary([folder], cache, SMALL)
    assert not again.built and again.vocabulary.key == vocabulary.key
    copy = shutil.copytree(folder, tmp_path / "copy")
    assert build_vocabulary([copy], cache, SMALL).vocabulary.key == vocabulary.key
    # A changed image or other parameters: another vocabulary.
    cv2.imwrite(str(copy / "img0.png"), _scene(99))
    assert build_vocabulary([copy], cache, SMALL).vocabulary.key != vocabulary.key
    other = VocabularyParams(words=8, max_features=60, max_side=320, iterations=10)
    assert build_vocabulary([folder], cache, other).vocabulary.key != vocabulary.key


def test_a_vocabulary_key_as_bows_file_tells_how_to_find_its_file(tmp_path: Path, cache_dir: Path) -> None:
    """From Python, bow's ``file`` is the vocabulary's file: its key (what ``--vocabulary`` takes
    too) is refused naming ``file`` and the call that gives the key's file, which works."""
    from wiloc import api
    from wiloc.descriptors.registry import get_descriptor

    key = build_vocabulary([_folder(tmp_path / "train", range(6))], Cache(cache_dir), SMALL).vocabulary.key
    with pytest.raises(ParameterError, match=re.escape(f"wiloc.api.vocabulary_file({key!r})")) as err:
        get_descriptor("bow", file=key)
    assert err.value.parameter == "file"
    assert get_descriptor("bow", file=api.vocabulary_file(key, Cache(cache_dir))).params["vocabulary"] == key
    with pytest.raises(ValueError, match=re.escape("got None; vocabulary= is the key read from that file, got '/v.h5'")):
        get_descriptor("bow", vocabulary="/v.h5")  # the file given where its key goes


def test_orb_vocabulary_and_unreadable_frames(tmp_path: Path, cache_dir: Path) -> None:
    folder = _folder(tmp_path / "train", range(5))
    (folder / "img9.png").write_bytes(b"not an image")
    params = VocabularyParams(feature="orb", words=16, max_features=60, max_side=320, iterations=10)
    report = build_vocabulary([folder], Cache(cache_dir), params)
    assert report.vocabulary.centres.dtype == np.uint8 and report.vocabulary.centres.shape == (16, 32)
    assert [name for name, _ in report.failed] == [str(folder / "img9.png")]
    assert len(report.vocabulary.training_frames) == 5


def test_the_command_line_takes_every_vocabulary_parameter_as_declared(tmp_path: Path, cache_dir: Path) -> None:
    """`wiloc vocabulary`'s options are VocabularyParams' declarations: one per field, with its
    default, and a value the parameter refuses is a usage error naming the option before any work."""
    from typer.testing import CliRunner

    from wiloc.cli import app
    from wiloc.parameters import declared

    runner = CliRunner()
    text = runner.invoke(app, ["vocabulary", "--help"], env={"COLUMNS": "400"}).stdout
    for d in declared(VocabularyParams):
        line = next(line for line in text.splitlines() if f"│ --{d.name.replace('_', '-')} " in line)
        assert f"[default: {d.default}]" in line, line
    folder = _folder(tmp_path / "train", range(2))
    for flag, value in [("--words", "1"), ("--max-side", "8"), ("--feature", "surf")]:
        result = runner.invoke(app, ["vocabulary", str(folder), flag, value, "--cache", str(cache_dir)])
        assert result.exit_code == 2, result.output
        assert result.output.startswith(f"error: {flag}: "), result.output
    assert not (cache_dir / "vocabularies").exists() or not list((cache_dir / "vocabularies").glob("*.h5"))


def test_a_vocabulary_is_the_same_whatever_the_processes_extracting_its_features(tmp_path: Path) -> None:
    folder = _folder(tmp_path / "train", range(40))
    serial = build_vocabulary([folder], Cache(tmp_path / "one"), SMALL, jobs=1).vocabulary
    parallel = build_vocabulary([folder], Cache(tmp_path / "two"), SMALL, jobs=2).vocabulary
    assert parallel.key == serial.key and parallel.training_frames == serial.training_frames
    assert np.array_equal(parallel.centres, serial.centres)
    assert np.array_equal(parallel.training_occurrences, serial.training_occurrences)
    assert len(list((tmp_path / "two" / "features").rglob("*.h5"))) == 40


def test_the_command_takes_the_processes_that_extract_features(tmp_path: Path, cache_dir: Path) -> None:
    from typer.testing import CliRunner

    from wiloc.cli import app

    runner = CliRunner()
    folder = _folder(tmp_path / "train", range(6))
    small = ["--words", "16", "--max-features", "60", "--max-side", "320", "--iterations", "10"]
    refused = runner.invoke(app, ["vocabulary", str(folder), *small, "--jobs", "0", "--cache", str(cache_dir)])
    assert refused.exit_code == 2 and refused.output.strip() == "error: --jobs: must be at least 1, got 0"
    assert not (cache_dir / "features").exists()  # refused before any feature was extracted
    built = runner.invoke(app, ["vocabulary", str(folder), *small, "--jobs", "1", "--cache", str(cache_dir), "--json"])
    assert built.exit_code == 0, built.output
    key = json.loads(built.stdout)["results"][0]["key"]
    assert key == build_vocabulary([folder], Cache(tmp_path / "other"), SMALL).vocabulary.key


def test_damaged_features_in_the_cache_are_extracted_again_and_said_so(tmp_path: Path, cache_dir: Path) -> None:
    from typer.testing import CliRunner

    from wiloc.cli import app

    folder = _folder(tmp_path / "train", range(6))
    first = build_vocabulary([folder], Cache(cache_dir), SMALL)
    files = sorted((cache_dir / "features").rglob("*.h5"))
    files[2].write_bytes(files[2].read_bytes()[:100])  # cut short, as a full disk might have left it
    first.path.unlink()  # the vocabulary is built again, from the cached features
    small = ["--words", "16", "--max-features", "60", "--max-side", "320", "--iterations", "10"]
    again = CliRunner().invoke(app, ["vocabulary", str(folder), *small, "--cache", str(cache_dir), "--json"])
    assert again.exit_code == 0, again.output
    report = json.loads(again.stdout)
    assert report["results"][0]["key"] == first.vocabulary.key
    assert any(f"{files[2]}: damaged local features; extracted again" in w for w in report["warnings"])
    assert np.array_equal(read_vocabulary(first.path).centres, first.vocabulary.centres)  # the same words


def test_describe_list_shows_the_local_features_kept(tmp_path: Path, cache_dir: Path) -> None:
    from typer.testing import CliRunner

    from wiloc.cli import app

    runner = CliRunner()
    build_vocabulary([_folder(tmp_path / "train", range(5))], Cache(cache_dir), SMALL)
    listed = json.loads(runner.invoke(app, ["describe", "--list", "--json", "--cache", str(cache_dir)]).stdout)
    kept = [r for r in listed["results"] if r["descriptor"] == "local features"]
    assert len(kept) == 1 and kept[0]["frames"] == 5 and kept[0]["complete"] and kept[0]["size"] > 0
    assert kept[0]["params"] == {**SMALL.feature_setting(), "libraries": {"opencv": cv2.__version__}}
    table = runner.invoke(app, ["describe", "--list", "--cache", str(cache_dir)], env={"COLUMNS": "200"}).stdout
    assert "local features" in table and "max_side=320" in table
    for path in (cache_dir / "features").rglob("*.h5"):
        path.write_bytes(b"not hdf5")
    listed = json.loads(runner.invoke(app, ["describe", "--list", "--json", "--cache", str(cache_dir)]).stdout)
    damaged = [r for r in listed["results"] if r["key"] == kept[0]["key"]]
    assert damaged[0]["descriptor"] == "unreadable" and "no readable local-features file" in damaged[0]["problem"]


def test_too_many_words_for_the_features_is_a_usage_error(tmp_path: Path, cache_dir: Path) -> None:
    folder = _folder(tmp_path / "train", range(2))
    with pytest.raises(ParameterError) as info:
        build_vocabulary([folder], Cache(cache_dir), VocabularyParams(words=5000, max_side=320))
    assert info.value.parameter == "words"
    assert not list((cache_dir / "vocabularies").glob("*.h5"))


@pytest.mark.parametrize("unreadable", [False, True])
def test_a_build_refused_after_extracting_leaves_no_journal(unreadable: bool, tmp_path: Path, cache_dir: Path) -> None:
    """Features refused (too few distinct ones for the words, no readable image) are refused again
    for the same frames and parameters: nothing of the build is left among the vocabularies (a
    journal of its features was, never to be used)."""
    folder = _folder(tmp_path / "train", range(2))
    if unreadable:
        for image in folder.iterdir():
            image.write_bytes(b"not an image")
    with pytest.raises(WilocError, match="no readable training image" if unreadable else "distinct training features"):
        build_vocabulary([folder], Cache(cache_dir), VocabularyParams(words=5000, max_side=320))
    assert list((cache_dir / "vocabularies").iterdir()) == []


@pytest.mark.parametrize("damage", ["nan centre", "fewer centres"])
@pytest.mark.parametrize("digest", ["as written", "of the damage"])
def test_a_vocabulary_file_of_damaged_centres_is_refused(damage: str, digest: str, tmp_path: Path,
                                                         cache_dir: Path) -> None:
    """A NaN centre is every feature's nearest word (argmin takes NaN first), so that every image
    held that one word alone and FAB-MAP ran on it, exit code 0; centres fewer than its words
    were read as they were. Changed on disk, they fail the file's checksum (a byte flipped in the
    centres gave other words and other results before); written so, with a digest of theirs, the
    check of the centres themselves refuses them."""
    from wiloc.bow.vocabulary import _digest

    path = build_vocabulary([_folder(tmp_path / "train", range(6))], Cache(cache_dir), SMALL).path
    with h5py.File(path, "a") as f:
        centres = f["centres"][()]
        del f["centres"]
        if damage == "nan centre":
            centres[3, 5] = np.nan
        f["centres"] = centres if damage == "nan centre" else centres[:-1]
        if digest == "of the damage":
            f.attrs["digest"] = _digest(f["centres"][()], [s.decode() for s in f["training/frames"][()]],
                                        f["training/words"][()])
    problem = ("its centres are not 16 rows of 128 finite values" if digest == "of the damage" else
               "its arrays fail their checksum")
    with pytest.raises(WilocError, match=rf"damaged vocabulary file: {problem}"):
        read_vocabulary(path)
    rebuilt = build_vocabulary([tmp_path / "train"], Cache(cache_dir), SMALL)
    assert rebuilt.built and rebuilt.repairs == [f"{path}: damaged vocabulary file: {problem}"
                                                 + (" (or an older wiloc wrote it without one)" if digest == "as written"
                                                    else "") + "; built again"]
    assert read_vocabulary(path).centres.shape == (16, 128)


def test_an_incomplete_file_is_not_a_vocabulary(tmp_path: Path) -> None:
    path = tmp_path / "half.h5"
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "wiloc-vocabulary"
    with pytest.raises(WilocError, match="not a complete"):
        read_vocabulary(path)
    with pytest.raises(WilocError, match="no such"):
        read_vocabulary(tmp_path / "absent.h5")


_KILLED_BUILD = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    import wiloc.description.vocabulary_build as build
    from wiloc.bow.vocabulary_params import VocabularyParams
    from wiloc.cache.store import Cache

    folder, marker, stage = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
    params = VocabularyParams(words=16, max_features=60, max_side=320, iterations=10)

    def stop_here():
        marker.write_text("now")
        time.sleep(120)

    def progress(done, total):
        if (stage == "features" and done == 2) or (stage == "clustering" and done == 7):
            stop_here()

    if stage == "writing":
        write = build.write_vocabulary
        def half_write(f, vocabulary, attrs):
            f.create_dataset("centres", data=vocabulary.centres)
            f.flush()
            stop_here()
        build.write_vocabulary = half_write
    build.build_vocabulary([folder], Cache(), params, progress=progress)
""")


@pytest.mark.parametrize("stage", ["features", "clustering", "writing"])
def test_a_killed_build_leaves_no_complete_file_and_the_rerun_resumes(
        tmp_path: Path, cache_dir: Path, stage: str, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = _folder(tmp_path / "train", range(6))
    marker = tmp_path / "marker"
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_BUILD, str(folder), str(marker), stage],
                            env={**os.environ, "WILOC_CACHE": str(cache_dir)}, cwd=REPO)
    deadline = time.monotonic() + 60
    while not marker.exists():
        assert proc.poll() is None, "the build ended before the kill"
        assert time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    folder_files = list((cache_dir / "vocabularies").iterdir())
    assert not [p for p in folder_files if p.suffix == ".h5"]  # no file that looks complete
    if stage == "writing":  # the file is built in memory and written once complete: nothing half-written
        assert not [p for p in folder_files if p.name.endswith(".wiloc-tmp")]
    import wiloc.description.frame_describing as framing
    import wiloc.description.vocabulary_build as build
    extracted = []
    real = build.extract_features
    for module in (build, framing):
        monkeypatch.setattr(module, "extract_features",
                            lambda *args, **kw: extracted.append(args[0]) or real(*args, **kw))
    rerun = build_vocabulary([folder], Cache(cache_dir), SMALL)
    # the cache kept the features of every frame finished before the kill: only the others are extracted again
    assert len(extracted) == (4 if stage == "features" else 0)
    assert not list((cache_dir / "vocabularies").glob("*.journal"))
    assert rerun.built and read_vocabulary(rerun.path).key == rerun.vocabulary.key
    assert not list((cache_dir / "vocabularies").glob("*.wiloc-tmp"))  # swept on the rerun
    fresh = build_vocabulary([folder], Cache(tmp_path / "fresh"), SMALL)
    assert np.array_equal(fresh.vocabulary.centres, rerun.vocabulary.centres)


# ----------------------------------------------------------------------------- bow descriptor

def test_bow_descriptor_through_workers_and_the_cache(tmp_path: Path, cache_dir: Path) -> None:
    cache = Cache(cache_dir)
    report = build_vocabulary([_folder(tmp_path / "train", range(6))], cache, SMALL)
    spec = get_descriptor("bow", file=report.path)
    assert spec.params == {"file": str(report.path), "vocabulary": report.vocabulary.key}
    assert (spec.metric, spec.dtype, spec.length, spec.natural_max) == ("hamming", np.uint8, 2, 16.0)
    assert get_descriptor("bow", file=report.path, vocabulary=report.vocabulary.key).key == spec.key
    with pytest.raises(ValueError, match="does not match"):
        get_descriptor("bow", file=report.path, vocabulary="0" * 24)
    with pytest.raises(ValueError, match="file="):
        get_descriptor("bow")
    image = _scene(3)
    assert np.array_equal(spec.compute(image), pack_words(report.vocabulary.bag_of_words(image)))

    query = _folder(tmp_path / "query", range(20, 28))
    serial = describe_folder(query, spec, cache, jobs=1).entry
    shutil.rmtree(cache_dir / "descriptors")
    shutil.rmtree(cache_dir / "features")  # the workers extract them again
    parallel = describe_folder(query, spec, cache, jobs=2).entry
    assert np.array_equal(serial.data, parallel.data) and serial.data.shape == (8, 2)
    assert np.array_equal(cache.read_entry(parallel.key).data, parallel.data)
    assert unpack_words(parallel.data, 16).any(axis=1).all()

    other = build_vocabulary([tmp_path / "train"], cache,
                             VocabularyParams(words=8, max_features=60, max_side=320, iterations=10))
    other_spec = get_descriptor("bow", file=other.path)
    assert other_spec.key != spec.key
    assert describe_folder(query, other_spec, cache).entry.key != parallel.key


def test_bow_computes_from_the_features_the_vocabulary_kept_in_the_cache(
        tmp_path: Path, cache_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Describing a vocabulary's training images with ``bow`` (in their folder, or as copies under
    other names) extracts no feature again: the cache kept them, by content, as the vocabulary was
    trained. The rows are those computed from the pixels."""
    import wiloc.description.frame_describing as framing

    cache = Cache(cache_dir)
    train = _folder(tmp_path / "train", range(6))
    spec = get_descriptor("bow", file=build_vocabulary([train], cache, SMALL).path)
    extracted = []
    real = framing.extract_features
    monkeypatch.setattr(framing, "extract_features", lambda *args, **kw: extracted.append(1) or real(*args, **kw))
    renamed = tmp_path / "renamed"
    renamed.mkdir()
    for k, image in enumerate(sorted(train.iterdir())):
        shutil.copy(image, renamed / f"frame{k:03d}.png")
    for folder in (train, renamed):
        entry = describe_folder(folder, spec, cache, jobs=1).entry
        pixels = [spec.compute(cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)) for name in entry.names]
        assert np.array_equal(entry.data, np.stack(pixels))
    assert extracted == []
    new = _folder(tmp_path / "new", range(30, 32))
    assert describe_folder(new, spec, cache, jobs=1).computed == 2 and len(extracted) == 2
    shutil.rmtree(cache_dir / "descriptors")
    assert describe_folder(new, spec, cache, jobs=1).computed == 2 and len(extracted) == 2  # kept the first time


def _described_then_damaged(tmp_path: Path, cache: Cache, frames: int,
                            damage: slice) -> tuple[DescriptorSpec, Entry, list[Path]]:
    """A bow spec, the entry of a query folder of `frames` images described with it (in this
    process) and, cut short since (as a full disk might have left them), the local-features
    files in the cache of its images `damage` picks; a copy of the folder, ``copy``, reads them."""
    spec = get_descriptor("bow", file=build_vocabulary([_folder(tmp_path / "train", range(6))], cache, SMALL).path)
    query = _folder(tmp_path / "query", range(20, 20 + frames))
    first = describe_folder(query, spec, cache, jobs=1)
    assert first.repairs == []
    store = FeatureStore(cache, SMALL.feature_setting())
    files = [store.path(fingerprint(query / name).digest) for name in first.entry.names][damage]
    for file in files:
        file.write_bytes(file.read_bytes()[:100])
        assert store.read(file.stem) is None
    shutil.copytree(query, tmp_path / "copy")  # the same images elsewhere: described anew, from the cache's features
    return spec, first.entry, files


def _check_repaired(report: DescribeReport, first: Entry, files: list[Path], cache: Cache) -> None:
    """Each damaged features file named in the report's repairs as a vocabulary build names it
    (and in the cache's, which ``localize`` reports), and valid again; the rows those of the run
    before the damage."""
    notes = sorted(f"{file}: damaged local features; extracted again" for file in files)
    assert sorted(report.repairs) == notes and sorted(cache.repairs) == notes
    assert all(FeatureStore(cache, SMALL.feature_setting()).read(file.stem) is not None for file in files)
    assert report.computed == len(first.names) and np.array_equal(report.entry.data, first.data)


def test_bow_extracts_damaged_local_features_again_and_says_so(tmp_path: Path, cache_dir: Path) -> None:
    """A local-features file damaged in the cache is never used by describing either: its
    features are extracted again, the file replaced and named in the report's repairs."""
    cache = Cache(cache_dir)
    spec, first, files = _described_then_damaged(tmp_path, cache, 4, slice(2, 3))
    _check_repaired(describe_folder(tmp_path / "copy", spec, cache, jobs=1), first, files, cache)


def test_damaged_local_features_a_worker_met_are_reported_too(tmp_path: Path, cache_dir: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """A worker process that meets a damaged features file sends the repair back with its results.
    Workers start after one frame timed here, and this process extracts slowly: they settle most."""
    import wiloc.description.frame_describing as framing

    cache = Cache(cache_dir)
    spec, first, files = _described_then_damaged(tmp_path, cache, 12, slice(None))
    for name in ("FORKED_START", "FRESH_START"):
        monkeypatch.setattr(framing, name, framing.WorkerStart(seconds=0.0, frames=1))
    here, parent, real = [], os.getpid(), framing.extract_features

    def slowly_here(*args: Any, **kw: Any) -> NDArray:
        if os.getpid() == parent:  # a forked worker inherits this patch, its own `here` too
            here.append(1)
            time.sleep(0.2)
        return real(*args, **kw)

    monkeypatch.setattr(framing, "extract_features", slowly_here)
    report = describe_folder(tmp_path / "copy", spec, cache, jobs=2)
    assert len(here) < len(files)  # the worker extracted the others
    _check_repaired(report, first, files, cache)


# ----------------------------------------------------------------------------- QA: reuse, causes, inputs

def test_a_vocabulary_file_under_another_keys_name_is_damaged_and_built_again(tmp_path: Path,
                                                                               cache_dir: Path) -> None:
    """A cache file named for one key that holds another vocabulary (copied over it) was reused as
    the one asked for: its key attribute is checked against its name, as a damaged file's arrays are."""
    from wiloc.bow.vocabulary import read_vocabulary_header

    folder, cache = _folder(tmp_path / "train", range(6)), Cache(cache_dir)
    fewer = VocabularyParams(words=8, max_features=60, max_side=320, iterations=10)
    first, second = build_vocabulary([folder], cache, SMALL), build_vocabulary([folder], cache, fewer)
    shutil.copyfile(first.path, second.path)
    problem = f"damaged vocabulary file: it holds vocabulary {first.vocabulary.key}, not {second.vocabulary.key}"
    with pytest.raises(WilocError, match=problem):
        read_vocabulary_header(second.path)  # what --vocabulary KEY reads
    again = build_vocabulary([folder], cache, fewer)
    assert again.built and again.vocabulary.key == second.vocabulary.key and again.vocabulary.n_words == 8
    assert again.repairs == [f"{second.path}: {problem} as its name says; built again"]
    assert read_vocabulary_header(second.path)[0] == second.vocabulary.key


@pytest.mark.parametrize("attribute", ["params", "n_words"])
def test_a_vocabulary_file_of_a_damaged_header_is_damaged_and_built_again(attribute: str, tmp_path: Path,
                                                                          cache_dir: Path) -> None:
    """Its parameters describe every frame's local features (max_side, max_features, ...) and its
    number of words unpacks every bag of words; no checksum covered them, so a flipped byte there
    (max_side 320 read as 328) changed every frame described with it, silently."""
    from wiloc.bow.vocabulary import read_vocabulary_header

    folder, cache = _folder(tmp_path / "train", range(6)), Cache(cache_dir)
    built = build_vocabulary([folder], cache, SMALL)
    with h5py.File(built.path, "a") as f:
        if attribute == "params":
            f.attrs["params"] = str(f.attrs["params"]).replace('"max_side": 320', '"max_side": 328')
        else:
            f.attrs["n_words"] = int(f.attrs["n_words"]) + 1
    problem = "damaged vocabulary file: its header fails its checksum"
    with pytest.raises(WilocError, match=problem):
        read_vocabulary_header(built.path)
    again = build_vocabulary([folder], cache, SMALL)
    assert again.built and again.repairs == [f"{built.path}: {problem}; built again"]
    assert read_vocabulary_header(built.path)[1] == SMALL


def test_a_reused_vocabulary_reports_the_frames_its_build_left_out(tmp_path: Path, cache_dir: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Reused from the cache, a vocabulary said no frame was left out; and from a relative folder
    the file kept relative paths of the frames left out, absolute ones of the frames used."""
    folder = _folder(tmp_path / "train", range(5))
    (folder / "img9.png").write_bytes(b"not an image")
    monkeypatch.chdir(tmp_path)
    built = build_vocabulary([Path("train")], Cache(cache_dir), SMALL)
    skipped = str((folder / "img9.png").resolve())
    assert built.built and [name for name, _ in built.failed] == [skipped]
    with h5py.File(built.path, "r") as f:
        assert json.loads(f.attrs["failed"]) == [list(item) for item in built.failed]
    reused = build_vocabulary([Path("train")], Cache(cache_dir), SMALL)
    assert not reused.built and reused.failed == built.failed


def test_an_undecodable_training_image_leaves_no_opencv_lines_on_stderr(tmp_path: Path, cache_dir: Path,
                                                                       capfd: pytest.CaptureFixture[str]) -> None:
    """A float TIFF, which OpenCV cannot decode to 8 bits, is left out and reported; OpenCV's own
    "[ERROR:0@...] imdecode_" line reached stderr before the vocabulary's own skipped line."""
    folder = _folder(tmp_path / "train", range(3))
    cv2.imwrite(str(folder / "float.tif"), np.dstack([_scene(7)] * 3).astype(np.float32) / 255)
    capfd.readouterr()
    report = build_vocabulary([folder], Cache(cache_dir), SMALL, jobs=1)
    assert [Path(name).name for name, _ in report.failed] == ["float.tif"]
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize(("words", "max_features", "cause"), [
    (40, 500, "--words 40 caps"), (1000, 30, "--max-features 30 caps"),
    (30, 20, "--words 30 and --max-features 20 cap"), (1000, 500, "images too small for local features")])
def test_a_sparse_vocabulary_names_its_cause(words: int, max_features: int, cause: str) -> None:
    """Fewer than 50 words, or a cap of fewer than 50 features per image, cannot give 50 words
    an image: the warning blamed the images for what the option does."""
    params = VocabularyParams(words=words, max_features=max_features)
    occurrences = np.zeros((10, words), dtype=bool)
    occurrences[:, :min(words, max_features, 40) // 2] = True
    vocabulary = Vocabulary("k", params, np.zeros((words, 128), np.float32), tuple(f"{i}.png" for i in range(10)),
                            occurrences)
    warning = vocabulary.too_few_words()
    assert warning is not None and cause in warning
    assert ("images too small" in warning) == (cause == "images too small for local features")


def test_training_images_without_features_name_the_folders(tmp_path: Path, cache_dir: Path) -> None:
    """Black images give no local feature: that is no --words value's fault (exit 2 said so); it
    is an error of the training folders, exit 1."""
    from typer.testing import CliRunner

    from wiloc.cli import app

    black = [tmp_path / "black", tmp_path / "dark"]
    for folder in black:
        folder.mkdir()
        for i in range(3):
            cv2.imwrite(str(folder / f"b{i}.png"), np.zeros((100, 100), np.uint8))
    with pytest.raises(WilocError) as info:
        build_vocabulary(black, Cache(cache_dir), VocabularyParams(words=2))
    assert not isinstance(info.value, ParameterError)
    assert info.value.where == f"{black[0]}, {black[1]}"
    assert info.value.problem.startswith("no local features in any training image")
    result = CliRunner().invoke(app, ["vocabulary", str(black[0]), "--words", "2", "--cache", str(cache_dir)])
    assert result.exit_code == 1 and result.stderr.startswith(f"error: {black[0]}: no local features"), result.output


@pytest.mark.parametrize("name", ["route.avi", "run.bag"])
def test_a_video_or_bag_is_no_training_folder(name: str, tmp_path: Path, cache_dir: Path) -> None:
    """A video is a traversal (guide.md): "a .avi file is not a traversal" was wrong; vocabulary
    takes image folders only."""
    stream = tmp_path / name
    stream.write_bytes(b"\0" * 64)
    with pytest.raises(WilocError, match=re.escape(f"{stream}: vocabulary trains from image folders only "
                                                   "(videos and ROS bags are not taken for training)")):
        build_vocabulary([stream], Cache(cache_dir), SMALL)
