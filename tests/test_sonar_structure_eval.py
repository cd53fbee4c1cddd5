"""The evaluation of registered structures: found only at the right place (position and yaw modulo the
model's symmetry); a registration at the wrong place is a false structure and its truth a miss. With
the truth's trajectory, the right place is judged relative to the estimated trajectory where the
structure was seen, so that a navigation error is not counted as the registration's."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.eval.metrics import sonar_metrics
from semslam.eval.structures import (
    POSITION_TOL_M,
    RELATIVE_POSITION_TOL_M,
    YAW_TOL_DEG,
    pose_at,
    registrations_of,
    relative_pose,
    structure_counts,
    structure_rows,
)
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


def test_a_structure_settled_by_its_passes_says_so():
    """metrics.json's row of a structure the final test confirmed only by its passes' votes says so (stop 46);
    the others' rows are as before (no key)."""
    settled = {**_registered("plet", (10.1, 5.0, 20.0), TRUE_YAW), "settled_by_passes": True}
    _, true, _ = _rows(settled, _registered("manifold", (30.0, 5.2, 20.0), 0.0, symmetry=2))
    assert true[1]["settled_by_passes"] is True
    assert "settled_by_passes" not in true[2]


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


# --- judged relative to the estimated trajectory (the navigation error where it was seen removed) ---


def _pose(position, yaw):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    T[:3, 3] = position
    return T


def _true_trajectory(stamps):
    """The vehicle's truth: a line north at 5 m east, heading north, 1 m/s."""
    return {int(s): _pose((float(s) * 1e-9, 5.0, 18.0), 0.0) for s in stamps}


STAMPS = [int(s * 1e9) for s in range(6, 15)]  # passing over the PLET at north 10
# a navigation error of 1.28 m, turned by 3° about the PLET
NAV_ERROR = _pose((1.0, -0.8, 0.1), 0.0) @ _pose((10.0, 5.0, 0.0), np.radians(3.0)) @ _pose((-10.0, -5.0, 0.0), 0.0)


def _seen_with(nav_error, registered_rel=np.eye(4), yaw=TRUE_YAW, stamps=STAMPS):
    """The PLET registered on data placed by a navigation that is off by ``nav_error`` (4×4, left
    multiplied: T_est = nav_error · T_true), with the registration's own error ``registered_rel``:
    the pose in the final map, its support, and the truth's pose_at."""
    truth = _true_trajectory(stamps)
    T_true_M = _pose((10.0, 5.0, 20.0), yaw)
    support = [{"stamp": s, "points": 100, "T_WB": (nav_error @ truth[s]).tolist()} for s in stamps]
    reg = _registered("plet", (0, 0, 0), 0.0)
    reg["pose"] = (nav_error @ T_true_M @ registered_rel).tolist()
    reg["support"] = support
    return reg, truth.get


def _judge(reg, truth_pose_at):
    block_rows = structure_rows([reg, _registered("manifold", (30.0, 5.0, 20.0), 0.0, 2)], TRUTH, truth_pose_at)
    return {r["truth_id"]: r for r in block_rows if r["truth_id"] is not None}, [
        r for r in block_rows if r["truth_id"] is None
    ]


def test_right_registration_under_a_navigation_error_is_found_relative():
    # the navigation is 1.3 m off and 3° turned where the PLET was seen: absolute 1.3 m / 3° from the
    # truth (beyond 1 m), but where the vehicle's map says, relative to the vehicle: found
    nav = NAV_ERROR
    reg, truth_pose_at = _seen_with(nav)
    true, false = _judge(reg, truth_pose_at)
    assert true[1]["found"] and true[1]["judged"] == "relative" and not false
    assert true[1]["relative_position_error_m"] == pytest.approx(0.0, abs=1e-9)
    assert true[1]["relative_yaw_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert true[1]["position_error_m"] > POSITION_TOL_M and true[1]["yaw_error_deg"] == pytest.approx(3.0)
    # without the truth's trajectory the same registration is judged absolute: a false structure
    true_abs, false_abs = _judge(reg, None)
    assert not true_abs[1]["found"] and false_abs[0]["judged"] == "absolute" and false_abs[0]["wrong_place"]


@pytest.mark.parametrize(
    "registration_error",
    [_pose((0.0, 0.0, 0.0), np.pi), _pose((0.8, 0.0, 0.0), 0.0)],  # end for end; slid 0.8 m along its x
)
def test_wrong_registration_is_wrong_relative_even_when_the_navigation_hides_it(registration_error):
    # the navigation is off by 0.5 m, and the registration by the opposite: absolutely close to the
    # truth, but not where the data put it
    nav = _pose((-0.4, 0.3, 0.0), 0.0)
    reg, truth_pose_at = _seen_with(nav, registered_rel=registration_error)
    true, false = _judge(reg, truth_pose_at)
    assert not true[1]["found"] and true[1]["registered_wrong_place"]
    (f,) = false
    assert f["wrong_place"] and f["judged"] == "relative"
    assert RELATIVE_POSITION_TOL_M < f["relative_position_error_m"] or f["relative_yaw_error_deg"] > YAW_TOL_DEG


def test_relative_pose_weights_the_patches_by_their_points():
    # two passes over the PLET, with navigation errors 0.2 m and 0.6 m north: the registration on their
    # blend is corrected by their mean weighted by the points each put on the structure (3:1)
    truth = _true_trajectory(STAMPS)
    T_true_M = _pose((10.0, 5.0, 20.0), TRUE_YAW)
    a, b = _pose((0.2, 0, 0), 0.0), _pose((0.6, 0, 0), 0.0)
    support = [{"stamp": STAMPS[0], "points": 300, "T_WB": (a @ truth[STAMPS[0]]).tolist()}]
    support += [{"stamp": STAMPS[1], "points": 100, "T_WB": (b @ truth[STAMPS[1]]).tolist()}]
    blended = _pose((0.3, 0, 0), 0.0) @ T_true_M
    rel = relative_pose(blended, support, truth.get)
    np.testing.assert_allclose(rel[:3, 3], T_true_M[:3, 3], atol=1e-9)
    # a stamp the truth does not cover is left out; none covered: no relative pose
    assert relative_pose(blended, support, lambda s: None) is None


def test_pose_at_interpolates_and_says_none_outside():
    from semslam.estimation import Trajectory

    traj = Trajectory(
        np.array([0, 10, 20], np.int64),
        np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0]]),
        np.array([Rotation.from_euler("z", a).as_quat() for a in (0.0, 0.2, 0.4)]),
    )
    at = pose_at(traj)
    T = at(15)
    np.testing.assert_allclose(T[:3, 3], [1.0, 0.5, 0.0])
    assert np.arctan2(T[1, 0], T[0, 0]) == pytest.approx(0.3)
    assert at(21) is None and at(-1) is None
    np.testing.assert_allclose(pose_at(traj, clip=True)(99)[:3, 3], [1.0, 1.0, 0.0])


def test_rows_keep_the_registration_so_it_can_be_judged_again():
    nav = NAV_ERROR
    reg, truth_pose_at = _seen_with(nav)
    block = sonar_metrics({"structures": [reg]}, TRUTH)  # as metrics.json has it: absolute
    assert block["structures_false"] == 1 and block["structures_judged"] == ["absolute"]
    again = structure_rows(registrations_of(block["structures"]), TRUTH, truth_pose_at)
    counts = structure_counts(again)
    assert (counts["structures_found"], counts["structures_false"], counts["structures_judged"]) == (1, 0, ["relative"])


def test_metrics_judge_relative_when_the_truths_trajectory_is_given():
    """metrics.json's sonar block (what run, compare and study write) judges with the truth's
    trajectory when the pipeline has it: the registration under a 1.3 m navigation error is found."""
    from semslam.estimation import Trajectory

    reg, _ = _seen_with(NAV_ERROR)
    truth = _true_trajectory(STAMPS)
    stamps = np.array(STAMPS, np.int64)
    trajectory = Trajectory(
        stamps,
        np.array([truth[s][:3, 3] for s in STAMPS]),
        Rotation.from_matrix([truth[s][:3, :3] for s in STAMPS]).as_quat(),
    )
    block = sonar_metrics({"structures": [reg]}, TRUTH, trajectory)
    row = next(r for r in block["structures"] if r["truth_id"] == 1)
    assert row["found"] and row["judged"] == "relative"
    assert not sonar_metrics({"structures": [reg]}, TRUTH)["structures"][0]["found"]  # absolute: 1.3 m off
