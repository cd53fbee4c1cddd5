"""The evaluation of registered structures: found only at the right place (position and yaw modulo the
model's symmetry); a registration at the wrong place is a false structure and its truth a miss."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.eval.metrics import sonar_metrics
from semslam.eval.structures import POSITION_TOL_M, YAW_TOL_DEG
from semslam.mission import GtStructure
from semslam.mission.ground_truth import GroundTruthMap

TRUE_YAW = 0.7
TRUTH = GroundTruthMap(
    structures=(
        GtStructure(1, "plet", (10.0, 5.0, 20.0), tuple(Rotation.from_euler("z", TRUE_YAW).as_quat())),
        GtStructure(2, "manifold", (30.0, 5.0, 20.0), tuple(Rotation.from_euler("z", 0.0).as_quat())),
    ),
)


def _registered(model, position, yaw, symmetry=1):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    T[:3, 3] = position
    return {"model": model, "pose": T.tolist(), "median_error_m": 0.01, "symmetry": symmetry}


def _rows(*registered):
    block = sonar_metrics({"structures": list(registered)}, TRUTH)
    return (
        block,
        {r["truth_id"]: r for r in block["structures"] if r["truth_id"] is not None},
        [r for r in block["structures"] if r["truth_id"] is None],
    )


def test_right_place_is_found_with_its_errors_and_symmetry():
    block, true, false = _rows(
        _registered("plet", (10.1, 5.0, 20.0), TRUE_YAW + np.radians(1.0)),
        # the manifold is 2-fold symmetric: half a turn is the same pose
        _registered("manifold", (30.0, 5.2, 20.0), np.pi + np.radians(0.5), symmetry=2),
    )
    assert true[1]["found"] and true[1]["position_error_m"] == pytest.approx(0.1)
    assert true[1]["yaw_error_deg"] == pytest.approx(1.0)
    assert true[2]["found"] and true[2]["yaw_error_deg"] == pytest.approx(0.5)
    assert not false
    assert (block["structures_found"], block["structures_missed"], block["structures_false"]) == (2, 0, 0)


@pytest.mark.parametrize(
    "position, yaw",
    [
        ((10.0, 5.0, 20.0), TRUE_YAW + np.pi),  # the right spot, the wrong way round
        ((10.0, 5.0 + POSITION_TOL_M + 0.2, 20.0), TRUE_YAW),  # the right heading, slid along
        ((10.0, 5.0, 20.0), TRUE_YAW + np.radians(YAW_TOL_DEG + 3)),
    ],
)
def test_wrong_place_is_a_false_structure_and_a_miss(position, yaw):
    block, true, false = _rows(_registered("plet", position, yaw), _registered("manifold", (30.0, 5.0, 20.0), 0.0, 2))
    assert not true[1]["found"] and true[1]["registered_wrong_place"]
    assert true[2]["found"]
    (f,) = false
    assert f["model"] == "plet" and not f["found"] and f["wrong_place"] and f["wrong_place_of"] == 1
    assert (block["structures_found"], block["structures_missed"]) == (1, 1)
    assert (block["structures_false"], block["structures_wrong_place"]) == (1, 1)


def test_far_from_any_truth_is_false_but_not_wrong_place():
    block, true, false = _rows(_registered("plet", (50.0, 50.0, 20.0), TRUE_YAW))
    (f,) = false
    assert not f["wrong_place"] and f["truth_id"] is None and not f["found"]
    assert not true[1]["found"] and not true[1]["registered_wrong_place"]
    assert block["structures_false"] == 1 and block["structures_wrong_place"] == 0
