"""Loop closure within one traversal: the online model and CAT-Graph against FAB-MAP, on Gardens Point.

As the paper's Section V.B runs it on Oxford City Centre: the online model against FAB-MAP in
sequence mode (no map: each frame is either a new place or a return to an earlier frame of the
same traversal), on loops put together from Gardens Point; and CAT-Graph on the same loops, as
Table I's "self" column runs it (one traversal localized against itself).

Each loop is one traversal of 400 frames, ``f0000``-``f0399``: Gardens Point ``day_right``
frames 0-199, then the same route again from another walk (``day_left``, the other side of the
path, or ``night_right``, at night). The frames are links to the dataset's images, never copies.
Frames 200-399 revisit frames 0-199; frames 0-199 are first visits, where any accepted match is
wrong. Ground truth: positions (each frame's place along the route, in frames), within 2 frames,
among the frames older than the recent window. FAB-MAP's vocabulary, which its Chow-Liu tree is
learned from too, is trained on the third traversal (``night_right`` for the day loop,
``day_left`` for the night loop), never on the loop's own images. Per method and loop: recall at
100 and 99 % precision, AP, R@1 over the revisits, the confidence's ECE and precision at 0.9 and
0.99, and the mean P(new place) over the first visits; the precision-recall curves in pr.png.

    python examples/loop_closure.py [DATA] [--out FOLDER] [--update-docs]
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from protocol import _finite, _fraction, _percent, localize, require, run_table_script, vocabulary

from wiloc import api
from wiloc.errors import WilocError
from wiloc.figures import plots

RADIUS = 2  # frames: the positions are place indices
ROUTE = 200  # frames of each Gardens Point walk
#: loop name: (first pass, revisit, the traversal FAB-MAP's vocabulary is trained on)
LOOPS = {"day_right+day_left": ("day_right", "day_left", "night_right"),
         "day_right+night_right": ("day_right", "night_right", "day_left")}
#: (table label, descriptor, method)
RUNS = (("online sad", "sad", "online"), ("online gist", "gist", "online"), ("FAB-MAP", "bow", "fabmap"),
        ("CAT-Graph sad", "sad", "catgraph"), ("CAT-Graph gist", "gist", "catgraph"))


def build_loop(root: Path, name: str, out: Path) -> Path:
    """The loop's folder of links (first pass, then revisit) and its positions file."""
    first, again, _ = LOOPS[name]
    folder = out / "loops" / name
    folder.mkdir(parents=True, exist_ok=True)
    sources = [api.frames(root / walk) for walk in (first, again)]
    if any(len(images) != ROUTE for images in sources):
        raise WilocError(root, f"expected {ROUTE} images in each of {first} and {again}")
    lines = ["name,x,y"]
    for k, image in enumerate(sources[0] + sources[1]):
        link = folder / f"f{k:04d}.jpg"
        if not link.is_symlink():
            link.symlink_to(image.resolve())
        lines.append(f"{link.name},{k % ROUTE},0")
    positions = out / "positions"
    positions.mkdir(exist_ok=True)
    (positions / f"{name}.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return folder


def run(data: Path, out: Path) -> dict[str, Any]:
    """Every run of RUNS on every loop: the table, the PR curves and summary.json."""
    root = data / "gardens-point-walking"
    require([root / walk for walk in ("day_right", "day_left", "night_right")])
    out.mkdir(parents=True, exist_ok=True)
    paths, rows = [], []
    for name, (_, _, trained_on) in LOOPS.items():
        folder = build_loop(root, name, out)
        report = vocabulary([root / trained_on])
        for label, descriptor, method in RUNS:
            params = {"file": str(report.path)} if descriptor == "bow" else {}
            result = localize(folder, descriptor=descriptor, descriptor_params=params, method=method,
                              out=out / "results" / f"{name}-{descriptor}-{method}.csv")
            paths.append(result.path)
            rows.append({"label": label, "loop": name, "vocabulary": trained_on if descriptor == "bow" else None})
    truth = api.TruthSource(kind="positions", path=str(out / "positions" / "{query}.csv"), radius=RADIUS)
    comparison = api.compare(paths, truth)
    table = []
    for row, e in zip(rows, comparison.evaluations):
        s, cuts = e.summary.as_dict(), e.calibration.cuts
        at = dict(zip(cuts.cuts, cuts.precision))
        first_visits = ~np.asarray(e.truth.has_match())
        new_place = e.results.frames.get("new_place")
        table.append({**row, "recall@100": s["recall_at_100"], "recall@99": s["recall_at_99"], "auc": s["auc"],
                      "R@1": s["recall_at_1"], "ece": e.calibration.ece, "precision@0.9": at.get(0.9),
                      "precision@0.99": at.get(0.99),
                      "new_place_first_visits": None if new_place is None
                      else float(np.nanmean(new_place.to_numpy()[first_visits]))})
    plots.plot_pr({f"{row['label']} {row['loop']}": e.curve for row, e in zip(rows, comparison.evaluations)},
                  out / "pr.png", title="Loop closure within one traversal (Gardens Point)")
    summary = _finite({"experiment": "loop_closure", "ground_truth": f"positions within {RADIUS} frames",
                       "table": table})
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    print(render(summary))
    return summary


def render(summary: dict[str, Any]) -> str:
    """The markdown table docs/results.md quotes."""
    lines = ["| method | loop | vocabulary trained on | recall @100 % | @99 % | AP | R@1 (revisits) | ECE | "
             "precision at 0.9 / 0.99 | P(new place), first visits |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for row in summary["table"]:
        auc = "-" if row["auc"] is None else f"{row['auc']:.3f}"
        lines.append(f"| {row['label']} | {row['loop']} | {row['vocabulary'] or '-'} | {_percent(row['recall@100'])} | "
                     f"{_percent(row['recall@99'])} | {auc} | {_percent(row['R@1'])} | {_fraction(row['ece'])} | "
                     f"{_fraction(row['precision@0.9'])} / {_fraction(row['precision@0.99'])} | "
                     f"{_fraction(row['new_place_first_visits'])} |")
    return "\n".join(lines)


def main() -> None:
    run_table_script("loop_closure", __doc__.splitlines()[0], run, render)


if __name__ == "__main__":
    main()
