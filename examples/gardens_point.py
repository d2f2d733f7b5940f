"""Gardens Point Walking: map day_right; queries day_left (viewpoint) and night_right (illumination).

Reproduces the paper's protocols (Table I, Table II, Figure 5, Figure 1) with aligned ground truth,
+-2 frames. The ``trained`` comparator for one query is trained on the OTHER query against the
same map (labelled with the same aligned ground truth), never on the pair it is tested on.

    python examples/gardens_point.py [DATA] [--out FOLDER] [--update-docs] [--descriptors sad,gist,brisk-gist]
"""
from __future__ import annotations

from pathlib import Path

from protocol import Experiment, aligned, main, parse_args, require

from wiloc import api

TOLERANCE = 2


def build() -> tuple[Experiment, Path, bool]:
    """The Gardens Point experiment from the command line."""
    args = parse_args("gardens_point", __doc__.splitlines()[0], descriptors=True)
    root = args.data / "gardens-point-walking"
    reference, queries = root / "day_right", [root / "day_left", root / "night_right"]
    require([reference, *queries])

    def training(query: Path) -> api.Training:
        other = next(q for q in queries if q != query)
        return api.Training(other, reference, aligned(TOLERANCE))

    experiment = Experiment(
        name="gardens_point", reference=reference, queries=queries,
        descriptors=[d.strip() for d in args.descriptors.split(",") if d.strip()],
        training=training, training_note="each query's model is trained on the other query "
                                          "(day_left <-> night_right) against day_right",
        tolerance=TOLERANCE)
    return experiment, args.out, args.update_docs


if __name__ == "__main__":
    main(build)
