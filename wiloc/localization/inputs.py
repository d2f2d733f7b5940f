"""A run's inputs prepared before describing: a folder's frames in the order runs read them,
external descriptors imported, visual vocabularies built or found, and worker processes shared by
several describes (``wiloc.api`` offers these as its own functions)."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any

from wiloc.bow.vocabulary_params import VocabularyParams
from wiloc.cache.store import Cache
from wiloc.description.describing import DescribeReport, traversal_paths
from wiloc.description.matrix_import import import_matrix, import_to_file
from wiloc.description.traversals import Progress, stage
from wiloc.description.vocabulary_build import VocabularyReport, build_vocabulary, vocabulary_path
from wiloc.description.workers import keeping_pools
from wiloc.descriptors.external import recorded_metric
from wiloc.errors import ParameterError, WilocError
from wiloc.given import check_file_path
from wiloc.sources.frames import list_traversal


def frames(folder: str | Path) -> list[Path]:
    """The image files of a traversal folder in the order a batch run decides them: natural order
    (``img2`` before ``img10``, where ``sorted`` puts ``img10`` first), hidden and non-image files
    left out. What a ``Localizer`` is given frame by frame to decide as ``localize`` does."""
    return list(list_traversal(Path(folder)).frames)


def shared_workers() -> AbstractContextManager[None]:
    """Within this block, the describes of several folders share their worker processes (started
    once, stopped on leaving), as one ``wiloc describe`` call over several folders does."""
    return keeping_pools()


def import_descriptors(path: Path, *, metric: str | None = None, names: Path | None = None,
                       cache: Cache | None = None, out: Path | None = None, prefix: str = "") -> DescribeReport:
    """Bring external descriptors (NetVLAD, ...) into the cache: an N x D matrix file, hloc's
    ``global-feats-*.h5``, or (with ``out``) a folder of per-image ``.npy`` vectors. With ``out``
    they are written first to that wiloc descriptor file, which records names and metric, so that
    ``localize OUT.h5 --map MAP.h5`` needs neither again; ``prefix`` keeps the frames whose names
    begin with it (hloc's ``db/``, ``query/``). ``metric``: default the file's recorded one, else l1.
    A path, names or out that is no file's path, or a prefix that is no text, is a ParameterError
    naming it."""
    for name, value in (("path", path), ("names", names), ("out", out)):
        if value is not None or name == "path":
            check_file_path(value, name)
    if not isinstance(prefix, str):
        raise ParameterError("prefix", f"the text frame names begin with (db/, query/), got {type(prefix).__name__}")
    source = Path(path)
    metric = metric or recorded_metric(source) or "l1"
    if out is not None:
        return import_to_file(source, Path(out), Cache.given(cache), names, metric, prefix)
    if source.is_dir():
        raise ParameterError("out", f"{source}: a folder of .npy files is imported into a descriptor file; "
                                    "give one to write (FILE.h5)")
    if prefix:
        raise ParameterError("prefix", "keeps part of a file written to a descriptor file; give that file too")
    return import_matrix(source, Cache.given(cache), names, metric)


def vocabulary(folders: Sequence[str | Path] | str | Path, params: Mapping[str, Any] | None = None, *,
               cache: Cache | None = None, progress: Progress | None = None,
               jobs: int | None = None) -> VocabularyReport:
    """Build (or reuse from the cache) the visual vocabulary of the images in ``folders`` (one
    folder or several): local features clustered into words, for the ``bow`` descriptor and
    FAB-MAP (docs/fabmap.md); ``jobs`` processes extract the features (default: all cores)."""
    paths = traversal_paths(folders, "folders")
    return build_vocabulary(paths, Cache.given(cache), VocabularyParams.create(params),
                            progress=stage(progress, "vocabulary"), jobs=jobs)


def vocabulary_file(vocabulary: str | Path, cache: Cache | None = None) -> Path:
    """A vocabulary's file: ``vocabulary`` is the file, or the key of a vocabulary in the cache.
    A key the cache does not hold is a ParameterError (a wrong value, as an unknown name is); a
    path that is no file is a WilocError (a missing file)."""
    path = Path(vocabulary).expanduser()
    if path.is_file():
        return path
    if not str(vocabulary).isalnum():  # a path (a key is hexadecimal): the file is missing
        kind = "a folder, not a vocabulary file" if path.is_dir() else "file does not exist"
        raise WilocError(None, f"{vocabulary}: {kind} (a vocabulary is its file, or its key in the cache)",
                         parameter="vocabulary")
    in_cache = vocabulary_path(Cache.given(cache), str(vocabulary))
    if not in_cache.is_file():
        raise ParameterError("vocabulary", f"{str(vocabulary)!r} is neither a vocabulary file nor the key of one in "
                                           "the cache")
    return in_cache
