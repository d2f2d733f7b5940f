"""Nordland, 64x32 thumbnails: map summer, query winter (3576 frames each), descriptor sad.

Reproduces the paper's protocols (Table I, Table II, Figure 5, Figure 1) with aligned ground truth,
+-2 frames. Nordland has a single labelled pair, which is the test pair, so the ``trained``
comparator is trained on another environment: Gardens Point day_left against day_right.

    python examples/nordland.py [DATA] [--out FOLDER] [--update-docs]
"""
from __future__ import annotations

from pathlib import Path

from protocol import Experiment, aligned, main, parse_args, require

from wiloc import api

TOLERANCE = 2


def build() -> tuple[Experiment, Path, bool]:
    """The Nordland experiment from the command line."""
    args = parse_args("nordland", __doc__.splitlines()[0], descriptors=False)
    root = args.data / "nordland-summer-winter-64x32"
    gardens = args.data / "gardens-point-walking"
    reference, query = root / "summer", root / "winter"
    require([reference, query, gardens / "day_left", gardens / "day_right"])
    training = api.Training(gardens / "day_left", gardens / "day_right", aligned(TOLERANCE))
    experiment = Experiment(
        name="nordland", reference=reference, queries=[query], descriptors=["sad"],
        training=lambda _query: training,
        training_note="Gardens Point day_left against day_right (another environment: Nordland's "
                      "only labelled pair is the test pair)",
        tolerance=TOLERANCE)
    return experiment, args.out, args.update_docs


if __name__ == "__main__":
    main(build)
