"""Building a visual vocabulary from training folders, through the cache.

A vocabulary lives in ``<cache>/vocabularies/<key>.h5``. Its key hashes the file format
version, the parameters and the *content* of the training frames (each frame's content digest,
folder by folder in frame order), not the folders' paths: the same images elsewhere give the
same vocabulary, a changed image a new one.

A build holds the cache lock on its file from start to end, so two processes never build the
same vocabulary twice at once, and writes the file in one atomic step at the end: a killed
build leaves no file that looks complete (at most a temporary file, which the next write
removes once its process is gone). Each training frame's local features are journaled as they
are extracted (``<key>.features.journal``, the descriptor cache's crash-safe journal), so a
killed build resumes with the frames it had not reached; the journal goes once the vocabulary
is written, or once the features are refused (too few distinct ones, no readable image), which
they would be again.
"""
from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from wiloc.bow.features import DTYPES, WIDTHS, decode_size, extract_features
from wiloc.bow.vocabulary import FORMAT_VERSION, Vocabulary, read_vocabulary, train_vocabulary, write_vocabulary
from wiloc.bow.vocabulary_params import VocabularyParams
from wiloc.cache.entries import EntryHeader, FrameRecord
from wiloc.cache.store import Cache, Journal, scan_journal
from wiloc.errors import FrameError, WilocError
from wiloc.reprs import short_repr
from wiloc.sources.frames import Fingerprint, fingerprint, list_traversal, read_gray

VOCABULARIES = "vocabularies"
Progress = Callable[[int, int], None]


@short_repr
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


def _features(frame: Path, print_: Fingerprint, params: VocabularyParams) -> FrameRecord:
    """One training frame's local features (flattened), or why it could not be read."""
    try:
        gray = read_gray(frame, decode_size(params.max_side))
    except FrameError as exc:
        return FrameRecord(str(frame.resolve()), print_.size, print_.mtime_ns, print_.digest, None, exc.problem)
    found = extract_features(gray, params.feature, params.max_features, params.max_side)
    return FrameRecord(str(frame.resolve()), print_.size, print_.mtime_ns, print_.digest, found.ravel())


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
        journal_path = path.with_name(f"{key}.features.journal")
        header = EntryHeader.create(f"vocabulary:{key}", "local-features", params.as_dict(), "none", 1.0, None,
                                    DTYPES[params.feature], WIDTHS[params.feature])
        found, records, _ = scan_journal(journal_path)
        journaled = {r.name: r for r in records} if found == header else {}
        journal = Journal(journal_path, header)
        try:
            for done, frame in enumerate(frames, 1):
                record = journaled.get(str(frame.resolve()))
                if record is None or record.digest != prints[frame].digest:
                    record = _features(frame, prints[frame], params)
                    journal.append(record)
                if record.row is None:
                    failed.append((str(frame), record.reason))
                else:
                    names.append(record.name)
                    features.append(record.row.reshape(-1, WIDTHS[params.feature]))
                if progress is not None:
                    progress(done, total)
        finally:
            journal.close()
        step = None if progress is None else (lambda i: progress(len(frames) + i, total))
        try:
            if not names:
                raise WilocError(folders[0], "no readable training image")
            vocabulary = train_vocabulary(key, params, names, features, step)
        except WilocError:  # these frames and parameters (the key) are refused again: nothing to resume
            journal_path.unlink(missing_ok=True)
            raise
        count = int(sum(len(f) for f in features))
        seconds = time.perf_counter() - start
        with cache.atomic_h5(path) as f:
            write_vocabulary(f, vocabulary, {
                "training_folders": json.dumps([str(Path(p).resolve()) for p in folders]),
                "failed": json.dumps(failed), "features": count, "build_seconds": seconds,
                "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            })
        journal_path.unlink(missing_ok=True)
    if progress is not None:
        progress(total, total)
    return VocabularyReport(vocabulary, path, True, count, failed, time.perf_counter() - start)

