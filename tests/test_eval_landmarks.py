"""Landmark matching against ground truth: errors of the one-to-one assignment, and duplicates
counted by nearest truth so that a second estimate cannot hide behind an unseen neighbour."""

import numpy as np

from semslam.estimation import LandmarkEstimate
from semslam.eval.metrics import match_landmarks
from semslam.mission.ground_truth import GroundTruthMap, GtObject, GtPipe

# a pipe ending at a valve, and a parallel pipe 25 cm beside it (within the matching gate)
TRUTH = GroundTruthMap(
    objects=(GtObject(0, "valve", (1.0, 0.0, 4.5)),),
    pipes=(GtPipe(0, (0.0, 0.0, 4.5), (0.9, 0.0, 4.5), 0.05), GtPipe(1, (0.3, 0.25, 4.5), (0.9, 0.25, 4.5), 0.05)),
)


def _pipe(i, p, q):
    return LandmarkEstimate(i, "pipe", p=np.array(p, float), q=np.array(q, float))


def test_a_pipe_mapped_twice_is_a_duplicate_even_with_an_unmapped_neighbour_in_the_gate():
    # a one-to-one assignment alone would give the second estimate to the unmapped parallel pipe
    first = _pipe(10, (0.05, 0.01, 4.5), (0.85, 0.01, 4.5))
    second = _pipe(11, (0.4, 0.04, 4.52), (0.88, 0.03, 4.5))  # pipe 0 again, 3 cm off
    valve = LandmarkEstimate(12, "object", position=np.array([1.01, 0.0, 4.5]))
    matches, counts = match_landmarks([first, second, valve], TRUTH)
    assert counts == {"duplicates": 1, "spurious": 0}
    pipe_matches = {m.estimate_id: m.truth_id for m in matches if m.kind == "pipe"}
    assert pipe_matches[10] == 0  # the better estimate carries the error


def test_each_pipe_once_has_no_duplicate_and_far_estimates_are_spurious():
    a = _pipe(10, (0.05, 0.01, 4.5), (0.85, 0.01, 4.5))
    b = _pipe(11, (0.35, 0.26, 4.5), (0.85, 0.24, 4.5))
    far = _pipe(12, (5.0, 5.0, 4.5), (5.5, 5.0, 4.5))
    matches, counts = match_landmarks([a, b, far], TRUTH)
    assert counts == {"duplicates": 0, "spurious": 1}
    assert sorted((m.estimate_id, m.truth_id) for m in matches) == [(10, 0), (11, 1)]
