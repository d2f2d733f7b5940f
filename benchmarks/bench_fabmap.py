"""Single-frame FAB-MAP 1.0 on Gardens Point Walking: a sanity check, not a tuning run.

For each (training, map, query) triple, with every parameter at its default (vocabulary and
bags of words go through the cache, so a second run only times FAB-MAP itself):
build the vocabulary on the training walk, describe map and query walks as bags of words,
fit the Chow-Liu tree on the training images, add one place per map frame, and localise every
query frame as argmax of the posterior over map places (its posterior = confidence).
R@1: share of query frames whose best place lies within +-2 frames of the same file name.
Columns: vocabulary build seconds, mean words per training image, bag-of-words milliseconds per
image (one process), R@1, mean confidence of the decisions, mean p(new place), seconds to fit
the Chow-Liu tree and set up the sampled new-place model, FAB-MAP milliseconds per query frame.

    .venv/bin/python benchmarks/bench_fabmap.py ../shared/data [--feature sift|orb]
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from wiloc.bow.fabmap import ChowLiuTree, FabMap
from wiloc.bow.vocabulary import VocabularyParams, unpack_words
from wiloc.cache.store import Cache
from wiloc.description.describing import describe_folder
from wiloc.description.vocabulary_build import build_vocabulary
from wiloc.descriptors import get_descriptor
from wiloc.sources.frames import list_traversal

from bench_common import data_errors

RUNS = (("night_right", "day_right", "day_left"), ("day_left", "day_right", "night_right"))
TOLERANCE = 2


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="folder holding gardens-point-walking/")
    parser.add_argument("--feature", default="sift", choices=("sift", "orb"))
    args = parser.parse_args(argv)
    walks = args.data / "gardens-point-walking"
    with data_errors(parser):  # a walk missing or holding no frames stops here, before any run
        for walk in sorted({walk for run in RUNS for walk in run}):
            list_traversal(walks / walk)
    cache = Cache()
    print(f"{'training':12} {'map':10} {'query':12} {'K':>5} {'vocab s':>8} {'words/img':>9} "
          f"{'bow ms':>6} {'R@1':>6} {'mean conf':>9} {'p(new)':>7} {'tree s':>6} {'ms/frame':>8}")
    for training, reference, query in RUNS:
        report = build_vocabulary([walks / training], cache, VocabularyParams(feature=args.feature))
        vocabulary = report.vocabulary
        spec = get_descriptor("bow", file=report.path)
        bags, bow_ms = {}, []
        for walk in (reference, query):
            described = describe_folder(walks / walk, spec, cache, jobs=1)
            bags[walk] = (described.entry.names, unpack_words(described.entry.data, vocabulary.n_words))
            if described.computed:
                bow_ms.append(1000 * described.seconds / described.computed)
        start = time.perf_counter()
        tree = ChowLiuTree.fit(vocabulary.training_occurrences)
        fabmap = FabMap(tree, training=vocabulary.training_occurrences)
        tree_seconds = time.perf_counter() - start
        map_names, map_bags = bags[reference]
        for z in map_bags:
            fabmap.add_place(z)
        position = {name: i for i, name in enumerate(map_names)}
        query_names, query_bags = bags[query]
        hits, confidence, new = [], [], []
        start = time.perf_counter()
        for name, z in zip(query_names, query_bags):
            places, p_new = fabmap.posterior(z)
            best = int(np.argmax(places))
            hits.append(abs(best - position[name]) <= TOLERANCE)
            confidence.append(places[best])
            new.append(p_new)
        ms = 1000 * (time.perf_counter() - start) / len(query_names)
        print(f"{training:12} {reference:10} {query:12} {vocabulary.n_words:5d} "
              f"{report.seconds:8.1f} {vocabulary.training_occurrences.sum(1).mean():9.1f} "
              f"{f'{np.mean(bow_ms):6.1f}' if bow_ms else '-':>6} {np.mean(hits):6.3f} "  # '-': cached, not timed
              f"{np.mean(confidence):9.3f} {np.mean(new):7.3f} "
              f"{tree_seconds:6.2f} {ms:8.2f}")


if __name__ == "__main__":
    main()
