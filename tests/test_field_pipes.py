"""The sonar front-end's pipe views of one pass: a pipe crossing the track must be seen in enough
windows of that pass for the map to take it (``association.min_observations`` views within
``association.track_timeout_s``; a lawnmower's next pass over it comes 115-130 s later)."""

import numpy as np
import pytest

from frontends.sonar import SonarFrontend
from frontends.sonar.patches import transform
from semslam.config import AssociationConfig
from semslam.mission.measurements import GroundTruthPose, SonarSwath
from semslam.observations import LineObservation
from semslam.sim.field_mission import simulate_field
from tests.support.sonar_survey import survey_config


class _TruePoses:
    """The estimate view of a front-end run on the true poses."""

    def __init__(self):
        self.poses: dict[int, np.ndarray] = {}

    def pose_at(self, stamp):
        return self.poses.get(stamp)

    def landmarks(self):
        return []


@pytest.fixture(scope="module")
def survey():
    """Two 18 m lines over seed 23's field; its 0.25 m pipeline runs north-south across both lines, so
    a window of 6 patches (6 m of track) holds all that a pass sees of it."""
    cfg = survey_config(seed=23, lines=2, line_length_m=18.0, centre=(5.8, 6.0), sonar={"n_beams": 256})
    return simulate_field(cfg)


def _pipe_views(mission, pipes_config: dict) -> list[tuple[float, np.ndarray]]:
    """(stamp s, the view's two ends in {W} placed with the true pose) of every pipe view."""
    fe = SonarFrontend(
        mission.metadata,
        {"pipes": pipes_config, "recognition": {"enabled": False}, "swath_registration": {"enabled": False}},
    )
    view, T_BS, out = _TruePoses(), mission.metadata.extrinsic("sonar"), []
    for m in mission:
        if isinstance(m, GroundTruthPose):
            view.poses[m.stamp] = m.matrix()
        elif isinstance(m, SonarSwath):
            for o in fe.process(m, view):
                if isinstance(o, LineObservation):
                    T = view.poses[m.stamp] @ T_BS
                    out.append((m.stamp * 1e-9, transform(T, np.stack([o.p, o.q]))))
    return out


def _on_pipe(ends: np.ndarray, p: np.ndarray, q: np.ndarray, tol: float = 0.1) -> bool:
    d = (q - p)[:2] / np.linalg.norm((q - p)[:2])
    n = np.array([-d[1], d[0]])
    return bool(np.all(np.abs((ends[:, :2] - p[:2]) @ n) < tol))


def test_a_pipe_crossing_the_track_is_seen_often_enough_in_one_pass(survey):
    pipe = survey.metadata.ground_truth.pipes[0]
    p, q = np.asarray(pipe.p, float), np.asarray(pipe.q, float)
    needed = AssociationConfig().min_observations
    views = _pipe_views(survey, {})
    first = [t for t, w in views if _on_pipe(w, p, q)]
    t0 = min(t for t, _ in views)
    first_pass = [t for t in first if t - t0 < 30.0]  # the first line's views (the second starts ~50 s later)
    assert len(first_pass) >= needed, first_pass
    assert max(first_pass) - min(first_pass) < AssociationConfig().track_timeout_s
    # the cadence of the swath-registration windows (every 3 patches) gave the pass 2 views only
    coarse = [t for t, w in _pipe_views(survey, {"every_patches": 3}) if _on_pipe(w, p, q) and t - t0 < 30.0]
    assert len(coarse) < needed
