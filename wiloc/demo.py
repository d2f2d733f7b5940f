"""The generated route behind ``wiloc demo``: a small multi-traversal dataset with ground truth.

Nothing is downloaded and no photo is shipped. A long "street" is drawn procedurally (smooth
random textures, gradients, buildings with windows, trees, poles, signs; some facades repeat, as
real streets do, so that places alias) with a fixed seed, and seen through a moving 160 x 120
camera window. The reference traversal drives the street at a constant step; each query drives it
at a varying speed and with its own perceptual change:

- ``dusk``: darker, gamma-compressed, uneven lighting and strong sensor noise (JPEG);
- ``rain``: blurred, lower contrast, the window shifted sideways (vertically in the strip), JPEG;
- ``detour``: mild lighting change and noise; halfway it leaves the mapped street for a parallel
  one that the map never saw, then rejoins the street further on (those frames have no true
  match).

Ground truth is the positions form (SPEC.md section 7): ``route/positions/<traversal>.csv`` with
``name,x,y`` in metres (10 pixels of the strip are one metre; the parallel street lies 30 m off),
and frames within :data:`RADIUS_M` metres are the same place. The demo then runs the four verbs
through :mod:`wiloc.api` (describe; localize with online, threshold and catgraph; compare) with a
cache inside the output folder, and writes the tables and the three plots.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import TypeAlias

import cv2
import numpy as np
from numpy.typing import NDArray

from wiloc import api
from wiloc.atomic import written_whole
from wiloc.cache.store import Cache
from wiloc.reprs import short_repr
from wiloc.sources.frames import text_path

SEED = 2014
FRAME_W, FRAME_H = 160, 120
STRIP_H = 150  # the strip is taller than the window so that it can shift sideways
PX_PER_M = 10.0
STEP_PX = 8.0  # reference spacing: 0.8 m
REF_FRAMES = 200
DETOUR_Y_M = 30.0  # the parallel street of the detour
RADIUS_M = 2.0
METHODS = ("online", "threshold", "catgraph")
DESCRIPTOR = "sad"

Image: TypeAlias = NDArray[np.uint8]
Progress = api.Progress


@dataclass(frozen=True)
class Condition:
    """The perceptual change of one traversal, applied to every frame it sees."""

    gain: float = 1.0
    gamma: float = 1.0
    light_slope: float = 0.0  # brightness change from left to right edge, as a fraction
    contrast: float = 1.0
    blur: float = 0.0  # Gaussian sigma in pixels
    noise: float = 0.0  # sensor noise sigma in gray levels
    lateral_px: int = 0  # vertical window offset in the strip (sideways in the world)
    shadows: float = 0.0  # depth of this traversal's own smooth shadow pattern over the street
    jpeg_quality: int | None = None  # None: PNG

    def scene(self, world: Image, rng: np.random.Generator) -> Image:
        """The street as it is during this traversal: darkened by its own shadow pattern."""
        if self.shadows == 0:
            return world
        shade = 1.0 - self.shadows * _smooth_texture(rng, world.shape[0], world.shape[1], 16)
        return np.clip(world * shade[..., None], 0, 255).astype(np.uint8)

    def apply(self, frame: Image, rng: np.random.Generator) -> Image:
        """The frame as this traversal's camera saw it."""
        image = frame.astype(np.float32) / 255.0
        if self.blur > 0:
            image = cv2.GaussianBlur(image, (0, 0), self.blur)
        image = 0.5 + (image - 0.5) * self.contrast
        image = np.clip(image, 0.0, 1.0) ** self.gamma * self.gain
        image *= (1.0 + self.light_slope * np.linspace(-0.5, 0.5, image.shape[1], dtype=np.float32))[None, :, None]
        image = image * 255.0 + rng.normal(0.0, self.noise, image.shape).astype(np.float32)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class DemoRoute:
    """The generated traversals (image folders) and their positions CSVs."""

    reference: Path
    queries: list[Path]
    positions: Path

    def truth(self) -> api.TruthSource:
        """Positions ground truth: frames within RADIUS_M metres are the same place."""
        return api.TruthSource(kind="positions", path=str(self.positions / "{query}.csv"),
                               ref_path=str(self.positions / f"{self.reference.name}.csv"),
                               radius=RADIUS_M)


# --------------------------------------------------------------------------------------- the world

def _smooth_texture(rng: np.random.Generator, height: int, width: int, cell: int) -> NDArray[np.float32]:
    """Smooth random values in [0, 1]: coarse noise upsampled with cubic interpolation."""
    coarse = rng.random((height // cell + 2, width // cell + 2), dtype=np.float32)
    return np.clip(cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC), 0.0, 1.0)


def _colour(rng: np.random.Generator, low: int = 30, high: int = 230) -> tuple[int, int, int]:
    return tuple(int(v) for v in rng.integers(low, high, 3))  # type: ignore[return-value]


def _building(rng: np.random.Generator, canvas: Image, x0: int, x1: int) -> None:
    """A facade with a grid of windows and sometimes a door."""
    h = canvas.shape[0]
    top = int(rng.integers(10, h // 2))
    cv2.rectangle(canvas, (x0, top), (x1, h - 25), _colour(rng), -1)
    rows, cols = int(rng.integers(1, 5)), max(1, (x1 - x0) // int(rng.integers(12, 24)))
    wh, ww = int(rng.integers(5, 12)), int(rng.integers(4, 10))
    glass = _colour(rng, 0, 255)
    for r in range(rows):
        for c in range(cols):
            wx = x0 + 4 + c * (x1 - x0 - 8) // cols
            wy = top + 6 + r * (h - 40 - top) // max(rows, 1)
            cv2.rectangle(canvas, (wx, wy), (wx + ww, wy + wh), glass, -1)
    if rng.random() < 0.5:
        dx = int(rng.integers(x0, max(x0 + 1, x1 - 12)))
        cv2.rectangle(canvas, (dx, h - 45), (dx + 10, h - 25), _colour(rng, 0, 80), -1)


def _tree(rng: np.random.Generator, canvas: Image, x0: int, x1: int) -> None:
    """A trunk and a crown of overlapping discs."""
    h = canvas.shape[0]
    cx = (x0 + x1) // 2
    cv2.line(canvas, (cx, h - 25), (cx, h // 2), _colour(rng, 40, 110), int(rng.integers(3, 7)))
    green = np.array([rng.integers(20, 90), rng.integers(90, 200), rng.integers(20, 90)])
    for _ in range(int(rng.integers(3, 7))):
        centre = (cx + int(rng.integers(-15, 16)), h // 2 - int(rng.integers(0, 30)))
        shade = tuple(int(v) for v in np.clip(green + rng.integers(-30, 31, 3), 0, 255))
        cv2.circle(canvas, centre, int(rng.integers(8, 20)), shade, -1)


def _pole(rng: np.random.Generator, canvas: Image, x0: int, x1: int) -> None:
    """A pole with a sign (a polygon) and a few wires."""
    h = canvas.shape[0]
    cx = int(rng.integers(x0, x1))
    cv2.line(canvas, (cx, h - 25), (cx, int(rng.integers(5, 40))), _colour(rng, 60, 160), 3)
    sides = int(rng.integers(3, 9))
    angles = np.linspace(0, 2 * np.pi, sides, endpoint=False) + rng.random()
    r = int(rng.integers(6, 14))
    centre = np.array([cx, int(rng.integers(30, h // 2))])
    points = (centre + r * np.column_stack([np.cos(angles), np.sin(angles)])).astype(np.int32)
    cv2.fillPoly(canvas, [points], _colour(rng))
    for _ in range(int(rng.integers(1, 4))):
        cv2.line(canvas, (x0, int(rng.integers(0, 30))), (x1, int(rng.integers(0, 30))), (40, 40, 40), 1)


PLACE_KINDS = (_building, _tree, _pole)


def make_world(rng: np.random.Generator, width: int, height: int = STRIP_H,
               repeat: float = 0.1) -> Image:
    """A street strip: sky and road gradients, smooth textures and a sequence of distinct places.

    About ``repeat`` of the places copy a run of one to three earlier ones, recoloured and with a
    new pole in front: the perceptual aliasing that keeps recall at high precision from being
    trivial.
    """
    texture = _smooth_texture(rng, height, width, 12)
    sky = np.linspace(0.9, 0.5, height, dtype=np.float32)[:, None]
    base = 255.0 * (0.8 * sky + 0.2 * texture)
    tint = np.array(_colour(rng, 150, 255), dtype=np.float32) / 255.0
    canvas = np.ascontiguousarray((base[..., None] * tint).astype(np.uint8))
    road = _smooth_texture(rng, 25, width, 6)
    canvas[-25:] = (60 + 80 * road)[..., None].astype(np.uint8)
    x = 0
    places: list[tuple[int, int]] = []
    while x < width:
        if len(places) > 3 and rng.random() < repeat:
            first = int(rng.integers(len(places) - 2))
            src0, src1 = places[first][0], places[first + int(rng.integers(0, 3))][1]
            w = min(src1 - src0, width - x)
            shift = rng.integers(-25, 26, 3)
            canvas[:, x:x + w] = np.clip(canvas[:, src0:src0 + w].astype(np.int16) + shift, 0, 255)
            _pole(rng, canvas, x, min(x + w, width - 1))  # similar, not identical
        else:
            w = int(rng.integers(30, 90))
            PLACE_KINDS[int(rng.integers(len(PLACE_KINDS)))](rng, canvas, x, min(x + w, width - 1))
            places.append((x, min(x + w, width)))
        x += w
    return canvas


# ------------------------------------------------------------------------------------ the traversals

@dataclass(frozen=True)
class Drive:
    """One traversal: how it drives (frame positions in the strip) and what its camera does."""

    name: str
    condition: Condition
    speed_jitter: float = 0.0  # relative speed variation around the reference step
    detour: tuple[float, float] | None = None  # leave / rejoin the street at these map fractions


def _speeds(rng: np.random.Generator, n: int, jitter: float) -> NDArray[np.float64]:
    """Smoothly varying step lengths around STEP_PX (a driver speeding up and slowing down)."""
    if jitter == 0:
        return np.full(n, STEP_PX)
    wobble = np.convolve(rng.normal(0.0, 1.0, n + 20), np.ones(20) / np.sqrt(20), mode="valid")[:n]
    return STEP_PX * np.clip(1.0 + jitter * wobble, 0.4, 1.8)


def _path(rng: np.random.Generator, drive: Drive, map_len: float, detour_x0: float,
          detour_len: float) -> list[tuple[float, float, float]]:
    """Per frame: strip x of the window's left edge, and the position (x, y) in metres.

    On the detour the window reads the strip beyond the map while the position runs along the
    parallel street, DETOUR_Y_M metres off, from where the traversal left the mapped one.
    """
    steps = _speeds(rng, 4 * REF_FRAMES, drive.speed_jitter)
    x = float(rng.uniform(0.0, STEP_PX)) if drive.speed_jitter else 0.0
    leave, rejoin = (np.array(drive.detour) * map_len) if drive.detour else (np.inf, np.inf)
    lateral = drive.condition.lateral_px / PX_PER_M
    path: list[tuple[float, float, float]] = []
    on_detour = False
    for step in steps:
        if not on_detour and leave <= x < rejoin:
            on_detour, x = True, detour_x0
        elif on_detour and x >= detour_x0 + detour_len:
            on_detour, x = False, rejoin
        if not on_detour and x > map_len:
            break
        position = ((leave + x - detour_x0) / PX_PER_M, DETOUR_Y_M) if on_detour else (x / PX_PER_M, lateral)
        path.append((x, *position))
        x += step
    return path


def _write_positions(path: Path, names: list[str], xy: list[tuple[float, float]]) -> None:
    """A positions CSV ``name,x,y`` in metres."""
    with written_whole(path, "the positions file") as out:
        writer = csv.writer(out)
        writer.writerow(["name", "x", "y"])
        writer.writerows([name, f"{x:.2f}", f"{y:.2f}"] for name, (x, y) in zip(names, xy))


DRIVES = (
    Drive("reference", Condition()),
    Drive("dusk", Condition(gain=0.55, gamma=1.8, light_slope=0.6, noise=14.0, shadows=0.5, jpeg_quality=70),
          speed_jitter=0.25),
    Drive("rain", Condition(blur=1.6, contrast=0.6, noise=5.0, lateral_px=6, shadows=0.3, jpeg_quality=50),
          speed_jitter=0.25),
    Drive("detour", Condition(gain=1.1, gamma=0.8, light_slope=-0.4, noise=8.0, shadows=0.3, jpeg_quality=80),
          speed_jitter=0.15, detour=(0.45, 0.6)),
)


def make_demo_route(root: Path, seed: int = SEED, progress: Progress | None = None) -> DemoRoute:
    """Draw the street and write every traversal (image folder) and its positions CSV under ``root``."""
    text_path(root)  # OpenCV crashes writing to a path that is not UTF-8
    rng = np.random.default_rng(seed)
    map_len = STEP_PX * (REF_FRAMES - 1)
    detour_len = 0.2 * map_len
    detour_x0 = map_len + FRAME_W + STEP_PX
    world = make_world(rng, int(detour_x0 + detour_len + 2 * FRAME_W))
    top = (STRIP_H - FRAME_H) // 2
    folders = []
    for drive in DRIVES:
        folder = root / drive.name
        folder.mkdir(parents=True, exist_ok=True)
        path = _path(rng, drive, map_len, detour_x0, detour_len)
        scene = drive.condition.scene(world, rng)
        names = []
        for k, (x, _, _) in enumerate(path):
            centre = (x + FRAME_W / 2.0, top + drive.condition.lateral_px + FRAME_H / 2.0)
            frame = drive.condition.apply(cv2.getRectSubPix(scene, (FRAME_W, FRAME_H), centre), rng)
            quality = drive.condition.jpeg_quality
            name = f"frame{k:03d}.{'png' if quality is None else 'jpg'}"
            cv2.imwrite(str(folder / name), frame, [] if quality is None else [cv2.IMWRITE_JPEG_QUALITY, quality])
            names.append(name)
            if progress is not None:
                progress(f"generate {drive.name}", k + 1, len(path))
        _write_positions(root / "positions" / f"{drive.name}.csv", names, [p[1:] for p in path])
        folders.append(folder)
    return DemoRoute(reference=folders[0], queries=folders[1:], positions=root / "positions")


# ------------------------------------------------------------------------------------------ the run

@short_repr
@dataclass
class DemoReport:
    """What ``wiloc demo`` produced: the route, the comparison (Table I and II), the files written."""

    route: DemoRoute
    comparison: api.Comparison
    files: list[Path]


def run_demo(out_dir: Path, progress: Progress | None = None) -> DemoReport:
    """Generate the demo route under ``out_dir`` and run describe, localize and compare on it.

    Writes ``route/`` (images and positions CSVs), ``cache/``, ``results/<query>-<method>.csv``,
    ``table1.csv``, ``table2.csv`` and the plots ``pr.png`` (precision-recall), ``threshold.png``
    (the paper's Figure 5) and ``model.png`` (Figure 1, the online model learned on the first
    query).
    """
    from wiloc.figures import plots

    out_dir = Path(out_dir)
    route = make_demo_route(out_dir / "route", progress=progress)
    cache = Cache(out_dir / "cache")
    api.describe([route.reference, *route.queries], DESCRIPTOR, cache=cache, progress=progress)
    runs = [api.localize(query, reference=route.reference, descriptor=DESCRIPTOR, method=method,
                         out=out_dir / "results" / f"{query.name}-{method}.csv", cache=cache,
                         progress=progress)
            for method in METHODS for query in route.queries]
    comparison = api.compare([run.path for run in runs], route.truth())
    files = [run.path for run in runs]
    for name, table in (("table1.csv", comparison.table1), ("table2.csv", comparison.table2)):
        with written_whole(out_dir / name, "the table") as out:
            table.to_csv(out, index=False)
        files.append(out_dir / name)
    files.append(plots.plot_pr(api.pr_series(comparison),
                               out_dir / "pr.png", title="Demo route: precision-recall"))
    files.append(plots.plot_threshold(api.threshold_series(comparison), out_dir / "threshold.png"))
    online = next(run for run in runs if run.method == "online")
    files.append(plots.plot_model(online.decisions.model, out_dir / "model.png",
                                  title=f"Online model learned on '{online.query.name}'"))
    return DemoReport(route=route, comparison=comparison, files=files)
