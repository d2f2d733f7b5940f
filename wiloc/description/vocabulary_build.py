"""Building a visual vocabulary from training folders, through the cache.

A vocabulary lives in ``<cache>/vocabularies/<key>.h5``. Its key hashes the file format
version, the parameters and the *content* of the training frames (each frame's content digest,
folder by folder in frame order), not the folders' paths: the same images elsewhere give the
same vocabulary, a changed image a new one.

A build holds the cache lock on its file from start to end, so two processes never build the
same vocabulary twice at once, and writes the file in one atomic step at the end: a killed
build leaves no file that looks complete (at most a temporary file, which the next write
removes once its process is gone). Each training frame's local features are kept in the cache as
they are extracted (``wiloc.cache.features``, by the frame's content digest; on every core, by
describing's own machinery), so a killed build resumes with the frames it had not reached, and
describing the same images with ``bow`` later extracts nothing again.
"""
from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import closing
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from wiloc.bow.features import decode_size, extract_features
from wiloc.bow.vocabulary import (FORMAT_VERSION, KEY_DIGITS, REBUILD, Vocabulary, read_vocabulary,
                                  train_vocabulary, write_vocabulary)
from wiloc.bow.vocabulary_params import VocabularyParams
from wiloc.cache.features import FeatureStore, damaged_note
from wiloc.cache.store import Cache
from wiloc.description.describing import is_stream
from wiloc.description.frame_describing import check_jobs, compute
from wiloc.descriptors.base import Descriptor, DescriptorSpec
from wiloc.errors import FrameError, WilocError
from wiloc.quiet import decoders_quiet
from wiloc.reprs import short_repr
from wiloc.sources.frames import fingerprint, list_traversal, read_gray

VOCABULARIES = "vocabularies"
Progress = Callable[[int, int], None]


@short_repr
@dataclass(frozen=True)
class VocabularyReport:
    """What `build_vocabulary` did: the vocabulary, its file, whether it was built now (False:
    the cache held it), the training frames that could not be used, the time taken, and the
    damaged features files of the cache that were extracted again (``<file>: what`` lines)."""

    vocabulary: Vocabulary
    path: Path
    built: bool
    features: int
    failed: list[tuple[str, str]]
    seconds: float
    repairs: list[str] = field(default_factory=list)


def vocabulary_key(digests: Sequence[str], params: VocabularyParams) -> str:
    """The key of the vocabulary trained with `params` on frames of these content digests."""
    text = json.dumps([FORMAT_VERSION, json.loads(params.to_json()), list(digests)], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:KEY_DIGITS]


def vocabulary_name(key: str) -> str:
    """The name (relative path in the cache) of a vocabulary's file, as passed to `Cache.lock`."""
    return f"{VOCABULARIES}/{key}.h5"


def vocabulary_path(cache: Cache, key: str) -> Path:
    """Where the vocabulary with this key lives in `cache`."""
    return cache.root / vocabulary_name(key)


class _FeatureCount(Descriptor):
    """A frame's number of local features, as a descriptor computed from them: describing the
    training frames with it (``frame_describing.compute``, given a feature store) extracts their
    features into the cache on every core."""

    name = "local features"

    @classmethod
    def spec(cls, params: dict[str, Any]) -> DescriptorSpec:
        """For features extracted with the setting ``params``: frames decoded to its size (the
        rows, counts, are neither stored nor compared)."""
        return cls._spec(params, metric="l1", dtype=np.dtype(np.int64), length=1, scale=1.0,
                         min_size=decode_size(params["max_side"]), natural_max=None)

    @classmethod
    def from_features(cls, features: NDArray, params: Mapping[str, Any]) -> NDArray:
        return np.array([len(features)])


def _extract_missing(frames: Sequence[Path], digests: Sequence[str], store: FeatureStore, jobs: int,
                     progress: Progress | None, total: int) -> None:
    """The local features of those `frames` whose features the cache lacks, extracted and kept
    there by `jobs` processes (describing's own: this one, then also workers once that pays);
    ``progress(done, total)`` counts the frames whose features are kept (or that cannot be read).
    A damaged features file is there, so not missing: :func:`_features` replaces it and says so."""
    missing = [(frame, None) for frame, digest in zip(frames, digests) if not store.path(digest).exists()]
    done = len(frames) - len(missing)
    spec = _FeatureCount.spec(dict(store.setting))
    with closing(compute(spec, list(enumerate(missing)), jobs, store)) as results:
        for _ in results:
            done += 1
            if progress is not None:
                progress(done, total)


def _features(frame: Path, digest: str, store: FeatureStore, repairs: list[str]) -> NDArray:
    """One training frame's local features, from the cache when it holds them (the frame is then
    not decoded); FrameError when it cannot be read. A damaged features file is noted in
    ``repairs`` and replaced."""
    setting = store.setting

    def extract() -> NDArray:
        with decoders_quiet():  # their own lines (OpenCV's "imdecode_"): the frame is reported as left out
            gray = read_gray(frame, decode_size(setting["max_side"]))
        return extract_features(gray, **setting)

    return store.features(digest, extract, lambda file: repairs.append(damaged_note(file)))


def _stored_failed(path: Path) -> list[tuple[str, str]]:
    """The training frames the build of the vocabulary file at ``path`` left out, and why."""
    try:
        with h5py.File(path, "r") as f:
            return [(str(frame), str(problem)) for frame, problem in json.loads(f.attrs["failed"])]
    except (KeyError, ValueError, TypeError, OSError) as exc:
        raise WilocError(path, f"unreadable vocabulary file ({exc}); {REBUILD}") from exc


def build_vocabulary(folders: Sequence[Path], cache: Cache, params: VocabularyParams | None = None,
                     progress: Progress | None = None, jobs: int | None = None) -> VocabularyReport:
    """The vocabulary of the images in `folders` (each a traversal folder), from the cache when
    it holds it, else built now and stored. The training frames' local features are extracted
    by `jobs` processes (default: all cores), as describing computes descriptors.

    `progress(done, total)` counts training frames, then clustering rounds (total = frames +
    ``params.iterations``; clustering may finish early). Unreadable frames are left out and
    reported by their resolved paths (reused from the cache: those its file records). Raises
    CacheBusyError if another process builds the same vocabulary too long.
    """
    start = time.perf_counter()
    params = VocabularyParams() if params is None else params
    jobs = check_jobs(jobs)  # refused before any work, even when every feature is in the cache
    if not folders:
        raise WilocError(None, "a vocabulary needs at least one training folder")
    stream = next((Path(folder) for folder in folders if is_stream(Path(folder)) and Path(folder).exists()), None)
    if stream is not None:
        raise WilocError(stream, "vocabulary trains from image folders only (videos and ROS bags are not taken "
                                 "for training)")
    frames = [path for folder in folders for path in list_traversal(Path(folder)).frames]
    prints = {path: fingerprint(path) for path in frames}
    key = vocabulary_key([prints[path].digest for path in frames], params)
    path = vocabulary_path(cache, key)
    total = len(frames) + params.iterations
    repairs: list[str] = []
    with cache.lock(vocabulary_name(key)):
        if path.exists():
            try:
                vocabulary, failed = read_vocabulary(path), _stored_failed(path)
            except WilocError as exc:  # an unreadable file is rebuilt (and replaced atomically) below
                repairs.append(f"{path}: {exc.problem.removesuffix(f'; {REBUILD}')}; built again")
            else:
                if progress is not None:
                    progress(total, total)
                return VocabularyReport(vocabulary, path, False, 0, failed, time.perf_counter() - start)
        names, features, failed = [], [], []
        store = FeatureStore(cache, params.feature_setting())
        _extract_missing(frames, [prints[frame].digest for frame in frames], store, jobs, progress, total)
        for frame in frames:  # from the cache now; a frame that cannot be read is tried once more
            resolved = str(frame.resolve())  # as the file and --json name frames, used or not
            try:
                features.append(_features(frame, prints[frame].digest, store, repairs))
            except FrameError as exc:
                failed.append((resolved, exc.problem))
            else:
                names.append(resolved)
        step = None if progress is None else (lambda i: progress(len(frames) + i, total))
        where = ", ".join(str(folder) for folder in folders)
        if not names:
            raise WilocError(where, "no readable training image")
        if not any(len(f) for f in features):  # no --words could help
            raise WilocError(where, "no local features in any training image (blank, flat or too small images)")
        vocabulary = train_vocabulary(key, params, names, features, step)
        count = int(sum(len(f) for f in features))
        seconds = time.perf_counter() - start
        with cache.atomic_h5(path) as f:
            write_vocabulary(f, vocabulary, {
                "training_folders": json.dumps([str(Path(p).resolve()) for p in folders]),
                "failed": json.dumps(failed), "features": count, "build_seconds": seconds,
                "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            })
    if progress is not None:
        progress(total, total)
    return VocabularyReport(vocabulary, path, True, count, failed, time.perf_counter() - start, repairs)

