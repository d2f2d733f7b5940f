"""A saved localizer state's file: its JSON with the numpy arrays beside it in one .npz, written
atomically, and the digest that tells a state edited or damaged after saving."""
from __future__ import annotations

import hashlib
import json
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.atomic import written_whole
from wiloc.errors import WilocError, load_problem

DIGEST = "meta_digest"  # the member holding the digest of the others (:func:`state_digest`)


def write_state(path: Path, state: dict[str, Any]) -> None:
    """Write ``state`` (JSON-ready values and numpy arrays) to ``path``, atomically: a kill leaves
    the old file. Never over a file that is no saved state (a frame, a table of one's own)."""
    if other_file(path):
        raise WilocError(path, "the file there is no saved localizer state, and saving would replace it; give "
                               "another name, or remove it first")
    meta, arrays = state_parts(state)
    with written_whole(path, "the localizer state", binary=True) as out:
        np.savez(out, meta=np.array(meta), **{DIGEST: np.array(state_digest(meta, arrays))}, **arrays)


def read_state(path: Path, form: str, version: int) -> dict[str, Any]:
    """The state :func:`write_state` wrote to ``path``, of this ``form`` and ``version``; a
    WilocError naming the file for anything else: missing, a folder, no .npz, cut short, of
    another version, or changed since it was written (its digest)."""
    if not path.exists():
        raise WilocError(path, "file does not exist")
    if path.is_dir():
        raise WilocError(path, "a folder, not a saved localizer state (an .npz file Localizer.save wrote)")
    if path.is_file() and not zipfile.is_zipfile(path):  # np.load would take it for .npy or pickle
        raise WilocError(path, "damaged or truncated: it starts as an .npz file but cannot be read whole"
                         if starts_as_zip(path) else "not a saved localizer state (not an .npz file)")
    try:
        with np.load(path, allow_pickle=False) as data:
            text, digest = str(data["meta"]), str(data[DIGEST]) if DIGEST in data.files else None
            arrays = {key: data[key] for key in data.files if key not in ("meta", DIGEST)}
            meta = json.loads(text)
    except OSError as exc:  # unreadable (no permission)
        raise WilocError(path, f"cannot read file ({exc.strerror or exc})") from None
    except (ValueError, KeyError, EOFError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
        raise WilocError(path, f"not a saved localizer state ({load_problem(exc)})") from None
    if not isinstance(meta, dict) or meta.get("format") != form or meta.get("version") != version:
        raise WilocError(path, "not a saved localizer state of this wiloc version")
    if digest != state_digest(text, arrays):
        raise WilocError(path, "the state was changed after it was saved (its contents do not match their "
                               "digest): it cannot be continued")
    return join_arrays(meta, arrays)


def state_parts(state: dict[str, Any]) -> tuple[str, dict[str, NDArray]]:
    """``state`` as its JSON text and the arrays moved out of it (what a pickle holds too)."""
    arrays: dict[str, NDArray] = {}
    return json.dumps(split_arrays(state, "", arrays)), arrays


def state_whole(meta: str, arrays: dict[str, NDArray]) -> dict[str, Any]:
    """The inverse of :func:`state_parts`."""
    return join_arrays(json.loads(meta), arrays)


ARRAY = "__array__"  # marks, in a saved state's JSON, a value stored as an array of the .npz


def state_digest(meta: str, arrays: Mapping[str, NDArray]) -> str:
    """SHA-256 of a saved state's JSON and arrays (each with its name, dtype and shape): a state
    edited or damaged after saving is refused on loading rather than
    continued into errors, or into decisions no localizer made."""
    h = hashlib.sha256(meta.encode())
    for key in sorted(arrays):
        value = np.ascontiguousarray(arrays[key])
        h.update(json.dumps([key, value.dtype.str, value.shape]).encode())
        h.update(value.tobytes())
    return h.hexdigest()


def starts_as_zip(path: Path) -> bool:
    """Whether ``path`` starts as a zip archive (an .npz file) does: a state cut short by a full
    disk or a copy that stopped, whose end (the archive's directory) is gone."""
    try:
        with path.open("rb") as handle:
            return handle.read(4) == b"PK\x03\x04"
    except OSError:  # unreadable: reading it says why
        return False


def other_file(path: Path) -> bool:
    """Whether ``path`` holds a file (not empty) that is no saved state, which saving would
    replace: a frame, a table of one's own."""
    try:
        if not path.is_file() or path.stat().st_size == 0:
            return False
        if not zipfile.is_zipfile(path):
            return True
        with zipfile.ZipFile(path) as archive:
            return "meta.npy" not in archive.namelist()
    except (OSError, zipfile.BadZipFile):  # unreadable: the writing says what is wrong
        return False


def split_arrays(value: Any, key: str, arrays: dict[str, NDArray]) -> Any:
    """``value`` as JSON, its numpy arrays moved into ``arrays`` under dotted keys."""
    if isinstance(value, np.ndarray):
        arrays[key] = value
        return {ARRAY: key}
    if isinstance(value, dict):
        return {k: split_arrays(v, f"{key}.{k}" if key else str(k), arrays) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [split_arrays(v, f"{key}.{i}", arrays) for i, v in enumerate(value)]
    return value.item() if isinstance(value, np.generic) else value


def join_arrays(value: Any, arrays: dict[str, NDArray]) -> Any:
    """The inverse of :func:`split_arrays`."""
    if isinstance(value, dict):
        if set(value) == {ARRAY}:
            return arrays[value[ARRAY]]
        return {k: join_arrays(v, arrays) for k, v in value.items()}
    if isinstance(value, list):
        return [join_arrays(v, arrays) for v in value]
    return value
