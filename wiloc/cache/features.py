"""Images' local features kept in the cache, found by the image's content digest: a vocabulary's
training frames and the same images described with ``bow`` (in any folder, under any name) pay
the feature detector once.

One HDF5 file per image and feature setting, ``<root>/features/<setting>/<digest>.h5``
(``<setting>`` a hash of what the features depend on: detector, cap, image scale, and the version
of OpenCV, which decodes, resizes and extracts), holding the features (SIFT's whole-number values
as bytes) and a CRC-32 over the setting, the digest and the features' shape, dtype and values.
Written as every cache file is (:meth:`Cache.atomic_h5`: a kill leaves the old file or none, never
half of one); a file that cannot be read or fails its checksum counts as absent: the features are
extracted again and the file replaced. Files are immutable once written, so processes share them
without a lock (two writing the same image write the same bytes).
"""
from __future__ import annotations

import hashlib
import json
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from wiloc.cache.store import UNREADABLE, Cache, EntryInfo
from wiloc.descriptors.base import library_versions

FORMAT = "wiloc-features"
FORMAT_VERSION = 1
FEATURES = "features"
LISTED = "local features"  # what `describe --list` calls a setting's files
#: The libraries whose versions a setting's folder is keyed by (names of ``descriptors.base.LIBRARIES``).
FEATURE_LIBRARIES = ("opencv",)


def _checksum(setting: str, digest: str, features: NDArray) -> int:
    """CRC-32 of what a features file stores of an image."""
    head = json.dumps([setting, digest, list(features.shape), features.dtype.str])
    return zlib.crc32(head.encode() + np.ascontiguousarray(features).tobytes())


@dataclass(frozen=True)
class FeatureStore:
    """The local features of images with one feature setting (``setting``: the keyword
    arguments of the extractor, as JSON-ready values) in ``cache``; pickles into worker processes."""

    cache: Cache
    setting: Mapping[str, Any]

    @property
    def _text(self) -> str:
        """The setting and the versions of the libraries that extract the features, as canonical
        JSON (what the folder's name hashes and checksums cover): environments sharing a cache
        never mix their features."""
        return json.dumps({**self.setting, "libraries": library_versions(FEATURE_LIBRARIES)}, sort_keys=True)

    @property
    def folder(self) -> Path:
        """Where this setting's files live."""
        return self.cache.root / FEATURES / hashlib.sha256(self._text.encode()).hexdigest()[:24]

    def path(self, digest: str) -> Path:
        """The file of the image with content digest ``digest``."""
        return self.folder / f"{digest}.h5"

    def read(self, digest: str) -> NDArray | None:
        """The stored features of the image with content digest ``digest``; None when absent,
        unreadable or failing their checksum."""
        try:
            with h5py.File(self.path(digest), "r") as f:
                if f.attrs.get("format") != FORMAT or int(f.attrs.get("format_version", 0)) != FORMAT_VERSION:
                    return None
                features = f["features"][()].astype(np.dtype(str(f.attrs["dtype"])), copy=False)
                crc = int(f.attrs["crc32"])
        except (OSError, KeyError, ValueError, TypeError):
            return None
        return features if _checksum(self._text, digest, features) == crc else None

    def write(self, digest: str, features: NDArray) -> None:
        """Store ``features`` as those of the image with content digest ``digest`` (atomically):
        as bytes when that loses nothing (OpenCV's SIFT values are whole numbers from 0 to 255:
        a quarter of the space of float32), else as they are."""
        stored = features
        if features.dtype.kind == "f":
            with np.errstate(invalid="ignore"):  # a NaN has no byte: the values are kept as they are
                as_bytes = np.clip(features, 0, 255).astype(np.uint8)
            if as_bytes.astype(features.dtype).tobytes() == features.tobytes():  # read back bit for bit
                stored = as_bytes
        with self.cache.atomic_h5(self.path(digest)) as f:
            f.attrs.update(format=FORMAT, format_version=FORMAT_VERSION, setting=self._text, digest=digest,
                           dtype=features.dtype.str, crc32=_checksum(self._text, digest, features))
            f.create_dataset("features", data=stored)

    def features(self, digest: str, extract: Callable[[], NDArray],
                 damaged: Callable[[Path], None] | None = None) -> NDArray:
        """The image's stored features, else ``extract()``'s, stored now; ``damaged(file)`` is
        told of a file that was there but could not be read or failed its checksum."""
        found = self.read(digest)
        if found is None:
            if damaged is not None and self.path(digest).exists():
                damaged(self.path(digest))
            found = extract()
            self.write(digest, found)
        return found


def damaged_note(file: Path) -> str:
    """The repair line (``<file>: what``) a run reports for a damaged features file it replaced."""
    return f"{file}: damaged local features; extracted again"


def list_features(cache: Cache) -> list[EntryInfo]:
    """One line per feature setting the cache holds local features of (``describe --list``):
    the setting and OpenCV version (read from its newest readable file), the images kept, their
    bytes and when the newest was written; a setting none of whose files can be read is listed as
    unreadable."""
    infos = []
    for folder in sorted(p for p in (cache.root / FEATURES).glob("*") if p.is_dir()):
        stats = {}
        for path in folder.glob("*.h5"):
            try:
                stats[path] = path.stat()
            except FileNotFoundError:  # replaced or removed meanwhile
                continue
        if not stats:
            continue
        newest = sorted(stats, key=lambda p: stats[p].st_mtime, reverse=True)
        setting = next((s for s in map(_setting_of, newest) if s is not None), None)
        updated = datetime.fromtimestamp(stats[newest[0]].st_mtime, timezone.utc).isoformat(timespec="seconds")
        infos.append(EntryInfo(
            key=folder.name, folder="", descriptor=LISTED if setting is not None else UNREADABLE,
            params=setting or {}, frames=len(stats), complete=setting is not None,
            size=sum(st.st_size for st in stats.values()), updated=updated,
            problem="" if setting is not None else f"{folder}: no readable local-features file"))
    return infos


def _setting_of(path: Path) -> dict[str, Any] | None:
    """The feature setting a features file was written with; None when it cannot be read."""
    try:
        with h5py.File(path, "r") as f:
            return dict(json.loads(str(f.attrs["setting"])))
    except (OSError, KeyError, ValueError, TypeError):
        return None
