"""Building a visual vocabulary from training folders, through the cache.

A vocabulary lives in ``<cache>/vocabularies/<key>.h5``. Its key hashes the file format
version, the parameters and the *content* of the training frames (each frame's content digest,
folder by folder in frame order), not the folders' paths: the same images elsewhere give the
same vocabulary, a changed image a new one.

A build holds the cache lock on its file from start to end, so two processes never build the
same vocabulary twice at once, and writes the file in one atomic step at the end: a killed
build leaves no file that looks complete (at most a temporary file, which the next write
removes once its process is gone), and the next run starts the build again from scratch.
"""
from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from wiloc.cache import Cache
from wiloc.errors import FrameError, WilocError
from wiloc.features import decode_size, extract_features
from wiloc.frames import fingerprint, list_traversal, read_gray
from wiloc.vocabulary import (
    FORMAT_VERSION,
    Vocabulary,
    VocabularyParams,
    read_vocabulary,
    train_vocabulary,
    write_vocabulary,
)

VOCABULARIES = "vocabularies"
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class VocabularyReport:
    """What `build_vocabulary` did: the vocabulary, its file, whether it was built now (False:
    the cache held it), the training frames that could not be used, and the time taken."""

    vocabulary: Vocabulary
    path: Path
    built: bool
    features: int
    failed: list[tuple[str, str]]
    seconds: float


def vocabulary_key(digests: Sequence[str], params: VocabularyParams) -> str:
    """The key of the vocabulary trained with `params` on frames of these content digests."""
    text = json.dumps([FORMAT_VERSION, json.loads(params.to_json()), list(digests)], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def vocabulary_name(key: str) -> str:
    """The name (relative path in the cache) of a vocabulary's file, as passed to `Cache.lock`."""
    return f"{VOCABULARIES}/{key}.h5"


def vocabulary_path(cache: Cache, key: str) -> Path:
    """Where the vocabulary with this key lives in `cache`."""
    return cache.root / vocabulary_name(key)


def build_vocabulary(folders: Sequence[Path], cache: Cache, params: VocabularyParams | None = None,
                     progress: Progress | None = None) -> VocabularyReport:
    """The vocabulary of the images in `folders` (each a traversal folder), from the cache when
    it holds it, else built now and stored.

    `progress(done, total)` counts training frames, then clustering rounds (total = frames +
    ``params.iterations``; clustering may finish early). Unreadable frames are left out and
    reported. Raises CacheBusyError if another process builds the same vocabulary too long.
    """
    start = time.perf_counter()
    params = VocabularyParams() if params is None else params
    if not folders:
        raise WilocError(None, "a vocabulary needs at least one training folder")
    frames = [path for folder in folders for path in list_traversal(Path(folder)).frames]
    prints = {path: fingerprint(path) for path in frames}
    key = vocabulary_key([prints[path].digest for path in frames], params)
    path = vocabulary_path(cache, key)
    total = len(frames) + params.iterations
    with cache.lock(vocabulary_name(key)):
        if path.exists():
            try:
                vocabulary = read_vocabulary(path)
            except WilocError:
                pass  # an unreadable file is rebuilt (and replaced atomically) below
            else:
                if progress is not None:
                    progress(total, total)
                return VocabularyReport(vocabulary, path, False, 0, [],
                                        time.perf_counter() - start)
        names, features, failed = [], [], []
        for done, frame in enumerate(frames, 1):
            try:
                gray = read_gray(frame, decode_size(params.max_side))
            except FrameError as exc:
                failed.append((str(frame), exc.problem))
            else:
                names.append(str(frame.resolve()))
                features.append(extract_features(gray, params.feature, params.max_features,
                                                 params.max_side))
            if progress is not None:
                progress(done, total)
        if not names:
            raise WilocError(folders[0], "no readable training image")
        step = None if progress is None else (lambda i: progress(len(frames) + i, total))
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
    return VocabularyReport(vocabulary, path, True, count, failed, time.perf_counter() - start)

