"""Results files: one CSV per query traversal with a self-describing header.

Layout (documented in docs/formats.md): header lines start with ``# `` and hold ``key: value``
pairs (values of ``params``, ``model`` and ``reference_frames`` are JSON); the first is
``# wiloc-results: 1``. Then a plain CSV table, one row per query frame. Files are written to a
temporary name and renamed, so a killed run never leaves a file that looks complete.
"""
from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from wiloc.errors import WilocError
from wiloc.methods.base import Decisions
from wiloc.model import HistogramModel

FORMAT_VERSION = "1"
BASE_COLUMNS = ("frame", "match", "difference", "confidence", "stage")
JSON_KEYS = ("params", "descriptor_params", "model", "reference_frames")


@dataclass
class Results:
    """One localization run: what was run (``meta``) and what it decided (``frames``)."""

    meta: dict[str, Any]
    frames: pd.DataFrame
    reference_frames: list[str] = field(default_factory=list)

    @property
    def method(self) -> str:
        return str(self.meta.get("method", ""))

    @property
    def model(self) -> HistogramModel | None:
        data = self.meta.get("model")
        return HistogramModel.from_dict(data) if data else None

    @property
    def match_index(self) -> np.ndarray:
        """Reference positions of the matched frames (-1 when undecided)."""
        lookup = {name: i for i, name in enumerate(self.reference_frames)}
        return np.array([lookup.get(m, -1) if isinstance(m, str) else -1
                         for m in self.frames["match"]], dtype=np.int64)

    @property
    def confidence(self) -> np.ndarray:
        return self.frames["confidence"].to_numpy(dtype=np.float64)


def decisions_to_frame(decisions: Decisions, query_names: list[str], ref_names: list[str]) -> pd.DataFrame:
    """The per-frame table of a run, with frame names instead of positions."""
    matched = np.full(len(decisions), "", dtype=object)
    decided = decisions.match >= 0
    matched[decided] = np.asarray(ref_names, dtype=object)[decisions.match[decided]]
    table = {"frame": list(query_names), "match": matched, "difference": decisions.difference,
             "confidence": decisions.confidence, "stage": decisions.stage}
    table.update(decisions.columns)
    return pd.DataFrame(table)


def write_results(path: Path, decisions: Decisions, *, query_names: list[str], ref_names: list[str],
                  meta: dict[str, Any]) -> Results:
    """Write a results file atomically and return what was written."""
    frame = decisions_to_frame(decisions, query_names, ref_names)
    header = {"wiloc-results": FORMAT_VERSION, **meta, "frames": len(frame), "params": decisions.params,
              "model": decisions.model.to_dict() if decisions.model is not None else None,
              "reference_frames": list(ref_names)}
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise WilocError(path, f"cannot write the results file ({exc.strerror})") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as out:
            for key, value in header.items():
                text = json.dumps(value) if key in JSON_KEYS else str(value)
                out.write(f"# {key}: {text}\n")
            frame.to_csv(out, index=False, float_format="%.9g")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return Results(meta=header, frames=frame, reference_frames=list(ref_names))


def read_results(path: Path) -> Results:
    """Read a results file written by :func:`write_results`; WilocError when it is not one."""
    path = Path(path)
    if not path.is_file():
        raise WilocError(path, "results file does not exist")
    meta: dict[str, Any] = {}
    n_header = 0
    try:
        with path.open(encoding="utf-8") as handle:
            for line in handle:
                if not line.startswith("# "):
                    break
                key, sep, value = line[2:].rstrip("\n").partition(": ")
                if not sep:
                    raise WilocError(path, f"malformed header line {n_header + 1}")
                try:
                    meta[key] = json.loads(value) if key in JSON_KEYS else value
                except json.JSONDecodeError as exc:
                    raise WilocError(path, f"header '{key}' is not valid JSON ({exc.msg})") from None
                n_header += 1
    except UnicodeDecodeError:
        raise WilocError(path, "not a wiloc results file (not UTF-8 text)") from None
    if meta.get("wiloc-results") != FORMAT_VERSION:
        raise WilocError(path, "not a wiloc results file (no '# wiloc-results: 1' header)")
    try:
        frames = pd.read_csv(path, skiprows=n_header, dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, ValueError) as exc:
        raise WilocError(path, f"unreadable table: {exc}") from None
    missing = [c for c in BASE_COLUMNS if c not in frames.columns]
    if missing:
        raise WilocError(path, f"missing column(s): {', '.join(missing)}")
    if "frames" in meta and str(len(frames)) != meta["frames"]:
        raise WilocError(path, f"holds {len(frames)} rows, its header says {meta['frames']}: "
                               "the file is incomplete or was edited")
    if frames["frame"].duplicated().any():
        dup = frames["frame"][frames["frame"].duplicated()].iloc[0]
        raise WilocError(path, f"duplicate row for frame '{dup}'")
    for column in frames.columns.difference(["frame", "match", "stage"]):
        frames[column] = pd.to_numeric(frames[column], errors="coerce")
    return Results(meta=meta, frames=frames, reference_frames=list(meta.get("reference_frames") or []))
