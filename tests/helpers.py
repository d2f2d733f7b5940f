"""Helpers several test files share: generated traversals and images, a real traversal's first
frames as one of its own, a stand-in descriptor, a cache entry, the one-error-line check, and a
describe interrupted part way.

Test files import them from here (``from helpers import ...``), never from one another.
"""
from __future__ import annotations

import contextlib
import importlib.util
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import cv2
import numpy as np

from wiloc.cache.store import Cache, Entry


BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@contextlib.contextmanager
def benchmark_module(name: str) -> Iterator[ModuleType]:
    """``benchmarks/NAME.py`` imported as a module, with its folder on ``sys.path`` meanwhile (as
    when it runs as a script: it imports ``bench_common`` beside it)."""
    folder = str(BENCHMARKS)
    sys.path.insert(0, folder)
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the class is made
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(name, None)
        sys.modules.pop("bench_common", None)
        sys.path.remove(folder)


def places(n: int, seed: int = 0) -> list[np.ndarray]:
    """Distinct smooth random 96x64 scenes, one per place."""
    rng = np.random.default_rng(seed)
    scenes = []
    for _ in range(n):
        small = rng.uniform(0, 255, size=(8, 12)).astype(np.float32)
        scenes.append(cv2.resize(small, (96, 64), interpolation=cv2.INTER_CUBIC))
    return scenes


def loop_rows(rng: np.random.Generator, places: int, recent: int,
              memory: float | None = None, revisit_pace: int = 1) -> tuple[list[np.ndarray], np.ndarray]:
    """A first pass over ``places`` new places, then a revisit of them in order (every
    ``revisit_pace``-th place: at that multiple of the first pass's pace): each place a random
    look, neighbouring places alike (a smooth route), each frame its place's look plus noise. The
    looks drift as a random walk (the nearer two places, the more alike, at any distance) or,
    with ``memory``, as an AR(1) walk of that coefficient (alike over a few places, unrelated far
    apart). Returns sequence-mode rows (frame k against frames before k - ``recent``) and each
    frame's place."""
    steps = rng.normal(0.0, 1.0, (places, 64))
    if memory is None:
        walk = np.cumsum(steps, axis=0) * 0.3
    else:
        walk = steps.copy()
        for i in range(1, places):
            walk[i] = memory * walk[i - 1] + np.sqrt(1.0 - memory ** 2) * steps[i]
    look = walk + rng.normal(0.0, 1.0, (places, 64))
    route = np.r_[np.arange(places), np.arange(0, places, revisit_pace)]
    frames = look[route] + rng.normal(0.0, 0.35, (route.size, 64))
    differences = np.abs(frames[:, None, :] - frames[None, :, :]).mean(axis=2)
    rows = []
    for k in range(route.size):
        row = differences[k].copy()
        row[max(0, k - recent):] = np.inf
        rows.append(row)
    return rows, route


def write_traversal(folder: Path, scenes: list[np.ndarray], gain: float, seed: int) -> Path:
    """``scenes`` as ``folder/img{i}.png``, times ``gain`` plus noise seeded by ``seed``."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    for i, scene in enumerate(scenes):
        image = np.clip(scene * gain + rng.normal(0, 6, scene.shape), 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"img{i}.png"), image)
    return folder


NOTES = ("skipped ", "note ", "warning ")


def ends_in_one_error(result: Any, code: int, *fragments: str) -> None:
    """Exit ``code``, one stderr line ``error: ...`` holding each fragment and coming last (the
    lines before it, if any, are notes on frames left out), no traceback."""
    assert result.exit_code == code, (result.exit_code, result.output)
    *notes, last = result.stderr.strip().splitlines() or [""]
    assert last.startswith("error: ") and all(line.startswith(NOTES) for line in notes), result.stderr
    assert "Traceback" not in result.output
    for fragment in fragments:
        assert fragment in last, (fragment, last)


@dataclass(frozen=True)
class FakeSpec:
    """A cheap stand-in for a DescriptorSpec: the image area-resized to side x side."""

    params: dict[str, Any] = field(default_factory=lambda: {"side": 4})
    name: str = "fake"
    metric: str = "l1"
    dtype: np.dtype = np.dtype(np.float32)  # noqa: RUF009 - a dtype is immutable
    scale: float = 1.0
    min_size: tuple[int, int] | None = None
    natural_max: float | None = 255.0
    colour: bool = False  # computed from gray images, one by one, as DescriptorSpec's gray ones
    feature_setting: None = None  # computed from the pixels, not from local features

    @property
    def length(self) -> int:
        return self.params["side"] ** 2

    @property
    def cache_params(self) -> dict[str, Any]:
        return self.params

    def compute(self, gray: np.ndarray) -> np.ndarray:
        side = self.params["side"]
        return cv2.resize(gray, (side, side), interpolation=cv2.INTER_AREA).astype(np.float32).ravel()


def first_frames(folder: Path, dest: Path, count: int) -> Path:
    """``dest``, a new folder of symbolic links to ``folder``'s first ``count`` frames in wiloc's
    natural order, under their own names: a shorter traversal of the same images, for a test that
    reads no further (a describer then describes only those, never copying an image)."""
    from wiloc.sources.frames import list_traversal

    dest.mkdir(parents=True)
    for name in list_traversal(folder).frame_names[:count]:
        (dest / name).symlink_to(folder / name)
    return dest


def write_images(folder: Path, count: int, seed: int = 0, size: tuple[int, int] = (64, 48)) -> list[str]:
    """`count` smooth random images, alternating PNG and JPEG, named img0 .. img{count-1}."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    names = []
    for i in range(count):
        image = cv2.GaussianBlur(rng.integers(0, 256, (size[1], size[0]), dtype=np.uint8), (5, 5), 0)
        name = f"img{i}.{'png' if i % 2 else 'jpg'}"
        assert cv2.imwrite(str(folder / name), image)
        names.append(name)
    return names


def interrupt_after_six_frames(args: list[str], cache: Cache, sig: signal.Signals) -> subprocess.Popen:
    """Run ``python -c args...`` (a describe into ``cache``), send ``sig`` once the cache holds 6
    described frames, and return the ended process."""
    run = subprocess.Popen([sys.executable, "-c", *args], stderr=subprocess.PIPE)
    finished = 0
    deadline = time.monotonic() + 120
    while finished < 6 and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
        finished = sum(info.frames for info in cache.list_entries())
    assert run.poll() is None, "describe ended before it could be interrupted"
    run.send_signal(sig)
    run.wait(timeout=60)
    return run


def make_entry(key: str, rows: int, seed: int, metric: str = "l1", scale: float = 0.5, length: int = 48) -> Entry:
    """A small uint8 entry whose digest follows its content, as the cache's digests do."""
    data = np.random.default_rng(seed).integers(0, 256, (rows, length), dtype=np.uint8)
    return Entry(
        key=key, folder=f"/routes/{key}", descriptor="sad", params={}, metric=metric, scale=scale,
        natural_max=None, dtype=data.dtype.str, length=length,
        names=[f"{key}{i:04d}.png" for i in range(rows)], data=data,
        digest=f"{key}-{seed}-{rows}-{length}",
    )
