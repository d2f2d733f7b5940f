"""The whole-image CAT-Graph filter's declared parameters (``wiloc.methods.catgraph.filter``),
checked in one place; docs/catgraph.md and docs/calibration.md give the measurements behind
every default."""
from __future__ import annotations

from dataclasses import dataclass

from wiloc.errors import ParameterError
from wiloc.parameters import Parameters, param


@dataclass(frozen=True)
class CatGraphParams(Parameters):
    """Parameters of the whole-image CAT-Graph filter (docs/catgraph.md, docs/calibration.md);
    ``seed=None`` draws a fresh seed, so that decisions differ from run to run."""

    owner = "catgraph"
    particles: int = param(2000, "Number of particles.", low=1, high=1_000_000)
    seed: int | None = param(0, "Random seed: the same seed gives identical decisions.",
                             low=0)
    step_noise: float = param(0.15, "Motion noise, a fraction of each step.", low=0.0)
    noise_floor: float = param(0.0, "Motion noise floor, a fraction of the mean node spacing.", low=0.0)
    speed_noise: float = param(0.0, "Per-particle speed noise per frame (0: no velocity state).", low=0.0)
    speed_range: tuple[float, float] = param((-3.0, 3.0), "Range of the particles' paces when they drift "
                                                          "(low, high).")
    resample_ess: float = param(0.5, "Resample when the effective sample size falls below this share.",
                                low=0.0, high=1.0)
    reseed: float = param(0.01, "Share of particles re-seeded each frame at the best sequence score.",
                          low=0.0, high=1.0)
    reseed_top: int = param(1, "Nodes of best sequence score that re-seeded particles go to.", low=1)
    sequence_rate: float = param(0.1, "Rate of the leaky sequence score (about 1 / frames remembered).",
                                 low=0.0, high=1.0, low_open=True)
    sequence_speeds: tuple[float, ...] = param((1 / 3, 0.5, 2 / 3, 1.0, 1.5, 2.0, 3.0, -0.5, -2 / 3, -1.0, -1.5, -2.0),
                                               "Paces (map nodes per query frame; negative: the route driven the "
                                               "other way) of the sequence score; re-seeded particles move at the "
                                               "pace that scored best at their node (half of the forward ones at "
                                               "the map's pace).")
    start_paces: float = param(0.3, "Prior probability that the query does not move at the map's pace at its "
                                    "start (shared evenly by the other paces of sequence_speeds).",
                               low=0.0, high=1.0, high_open=True)
    rank_pace_min: float = param(0.5, "Paces slower than this (in magnitude) give re-seeded particles their "
                                      "pace but do not choose their nodes: a slow trajectory's sum favours map "
                                      "frames that resemble many query frames.", low=0.0)
    fast_pace: float = param(2.0, "Paces faster than this rank nodes apart from the others (their sum over few "
                                  "query frames spans many nodes, so it finds look-alikes more often).", low=0.0)
    reseed_fast: float = param(0.02, "Share of re-seeded particles that go to the best trajectory faster than "
                                     "fast_pace (when sequence_speeds has such paces).", low=0.0, high=1.0)
    reseed_backward: float = param(0.1, "Share of re-seeded particles that go to the best backward trajectory "
                                         "(when sequence_speeds has negative paces).", low=0.0, high=1.0)
    contrast_window: int = param(10, "Half window (nodes) of the sequence score's contrast normalisation.",
                                 low=1, high=100_000)  # each row takes time in proportion: 10**9 never ended
    frontier: int = param(60, "Sequence mode: frames before the recent window (exclude_recent) that are not yet "
                              "map nodes. A frame resembles the stretch walked just before it, so the map "
                              "keeps away from it (docs/catgraph.md).", low=0, sequence_only=True)
    mode_window: int = param(2, "Half window (nodes) around the decided node whose posterior mass is "
                                "the confidence: the ground truth's tolerance.", low=0)
    a0: float = param(0.5, "Prior shape of the same-place rank model Beta(a, 1), before any frame.",
                      low=0.0, high=1.0, low_open=True)
    n0: float = param(10.0, "Weight of that prior, in frames.", low=0.0, low_open=True)
    hub_weight: float = param(100.0, "Weight, in frames, of the prior that a map frame resembles query frames "
                                     "by chance no more than any other: each node's rank is read against the "
                                     "ranks it has had in the run's frames (0: every node alike).", low=0.0)
    a_min: float = param(0.02, "Smallest shape the rank model may learn (the sharpest evidence).",
                         low=0.0, high=1.0, low_open=True)
    jump: float = param(0.001, "Prior probability per frame of jumping elsewhere on the map.", low=0.0, high=1.0)
    leave: float = param(0.001, "Prior probability per frame of leaving the map (new place or blind spot).",
                         low=0.0, high=1.0, high_open=True)
    rejoin: float = param(0.001, "Prior probability per frame of rejoining the map once off it.",
                          low=0.0, high=1.0, high_open=True)
    unexplained0: float = param(0.5, "Probability that the map does not explain the first frame.",
                                low=0.0, high=1.0, low_open=True, high_open=True)
    departure_prior: tuple[float, float] = param((1.9, 0.1), "Beta prior (departures, blind spots) of the share "
                                                             "of off-map stretches that leave the map.", low=0.0)
    stretch_open: float = param(0.5, "An off-map stretch opens when P(unexplained) reaches this.",
                                low=0.0, high=1.0)
    stretch_close: float = param(0.1, "... and closes when it falls below this.", low=0.0, high=1.0)
    near_duplicate: float = param(0.25, "Map frames closer to their neighbours than this share of the "
                                        "median step count as less evidence (0: off).", low=0.0)
    repeat_standing: float = param(0.5, "Prior probability that a query standing on one repeated image (the same "
                                        "row again) stands still, against moving on while its camera repeats "
                                        "an image.", low=0.0, high=1.0)
    repeat_pace_spread: float = param(0.1, "Spread (sd of its log) of the pace of the particles that move on "
                                           "while an image repeats: no image tells the pace then, so it is known "
                                           "only roughly (0: exactly the particle's pace).", low=0.0, high=1.0)
    odometry_scale: float = param(0.05, "With odometry: spread (sd of its log) of each particle's factor between "
                                        "the query's odometry and the map's, kept for its life, so that a scale "
                                        "the two disagree by is learned by selection (0, with odometry_scale_wide "
                                        "0: the odometry as given).",
                                  low=0.0, high=1.0, odometry_only=True)
    odometry_scale_wide: float = param(0.3, "With odometry: the wider spread a tenth of the particles' factors "
                                            "are drawn with, for odometries of other kinds that disagree by more "
                                            "(wheels against a GPS map; 0: no factor drawn wider).", low=0.0,
                                       high=1.0, odometry_only=True)

    def check(self) -> None:
        low, high = self.speed_range
        if low > high:
            raise ParameterError("speed_range", f"must be (low, high) with low <= high, got {self.speed_range!r}")
        if self.stretch_close > self.stretch_open:
            raise ParameterError("stretch_close", f"must not exceed stretch_open ({self.stretch_open}), "
                                                  f"got {self.stretch_close}")
        if 0.0 in self.sequence_speeds:
            raise ParameterError("sequence_speeds", f"every pace must be non-zero, got {self.sequence_speeds!r}")
        if not any(abs(v) >= self.rank_pace_min for v in self.sequence_speeds):
            raise ParameterError("rank_pace_min", f"must leave a pace of sequence_speeds to rank nodes, got "
                                                  f"{self.rank_pace_min} for {self.sequence_speeds!r}")
        if min(self.departure_prior) <= 0:
            raise ParameterError("departure_prior", f"both counts must be > 0, got {self.departure_prior!r}")
