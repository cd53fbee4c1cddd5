"""Sonar front-end through the pipeline into the graph, on a short simulated survey: the entry
point, configuration errors, structure landmarks, and relative-pose constraints that reduce the
navigation error."""

import numpy as np
import pytest

from frontends.sonar import SonarFrontend
from semslam.config import SemslamConfig
from semslam.errors import ConfigError
from semslam.estimators import create_estimator
from semslam.eval.structures import pose_at, structure_rows
from semslam.observations import OdometryObservation, StructureObservation
from semslam.pipeline import run_pipeline
from semslam.registry import create_frontends
from semslam.sim.field_mission import simulate_field
from tests.support.sonar_survey import survey_config, true_structure_pose


@pytest.fixture(scope="module")
def mission():
    """Two 18 m lines of seed 23's field: its 0.25 m pipeline crosses their overlap north–south,
    the PLET lies under the second line and the manifold under the first. A drifting heading
    (2.5° over the survey) and a noisier DVL misalign the lines by 0.2–0.5 m."""
    return _survey(23)


@pytest.fixture(scope="module")
def baseline(mission):
    """The graph on navigation alone."""
    return _run(mission)[0]


@pytest.fixture(scope="module")
def structure_run(mission):
    """The graph with the sonar front-end, recognition without its final pass."""
    return _run(mission, {"recognition": {"final_pass": False}})


def _run(mission, fe_config=None):
    est = create_estimator("graph", mission.metadata, SemslamConfig())
    fes = [] if fe_config is None else [SonarFrontend(mission.metadata, fe_config)]
    res = run_pipeline(mission, [est], fes)
    return res, (fes[0] if fes else None)


def _second_line_error(res):
    """Mean horizontal position error over the second half of the mission (the second line)."""
    traj, truth = res.results["graph"].trajectory, res.truth
    t = traj.stamps
    keep = t >= t[0] + (t[-1] - t[0]) // 2
    P = np.column_stack([np.interp(t[keep], truth.stamps, truth.positions[:, k]) for k in range(3)])
    return float(np.mean(np.linalg.norm((traj.positions[keep] - P)[:, :2], axis=1)))


def test_registered_by_entry_point_and_config_errors_name_the_key(mission):
    (fe,) = create_frontends(["sonar"], mission.metadata, {"sonar": {}})
    assert isinstance(fe, SonarFrontend)
    with pytest.raises(ConfigError, match=r"^frontends\.sonar\.recognition\.delta_m: "):
        SonarFrontend(mission.metadata, {"recognition": {"delta_m": -1}})
    with pytest.raises(ConfigError, match=r"^frontends\.sonar\.patches\.lenght_m: "):
        SonarFrontend(mission.metadata, {"patches": {"lenght_m": 2}})
    with pytest.raises(ConfigError, match=r"frontends\.sonar\.recognition\.models: unknown structure model"):
        SonarFrontend(mission.metadata, {"recognition": {"models": ["submarine"]}})


def _survey(seed: int):
    """Two 18 m lines over ``seed``'s field (the fixture's survey: seed 23)."""
    cfg = survey_config(
        seed=seed,
        lines=2,
        line_length_m=18.0,
        centre=(5.8, 6.0),
        sonar={"n_beams": 256},
        ahrs={"heading_bias_drift_deg": 2.5},
        dvl={"sigma_m_s": 0.02, "random_dropout_rate": 0.0},
    )
    return simulate_field(cfg)


def test_swath_registration_makes_the_second_line_agree_with_the_first(mission, baseline):
    """Over four fields (the fixture's seed 23 and 24–26): the swath registrations between the lines are
    accepted on most, and they bring the second line nearer the truth in sum. One survey alone hangs on
    one or two borderline decisions (seed 23: one registration, accepted or rejected as the patches' border
    moves with any navigation change; experiments/estimators/README.md, stop 41), so the test is a sum."""
    accepted, before, after = 0, 0.0, 0.0
    for seed in (23, 24, 25, 26):
        m = mission if seed == 23 else _survey(seed)
        reg, _ = _run(m, {"recognition": {"enabled": False}, "pipes": {"enabled": False}})
        accepted += any(isinstance(r.observation, OdometryObservation) for r in reg.observations)
        before += _second_line_error(baseline if seed == 23 else _run(m)[0])
        after += _second_line_error(reg)
    assert accepted >= 3, accepted
    assert after < 0.95 * before, (before, after)


def test_structure_landmark_brings_the_second_line_nearer_the_truth(structure_run, baseline):
    res, _ = structure_run
    assert _second_line_error(res) < _second_line_error(baseline)


def test_structure_becomes_a_graph_landmark(mission, structure_run, tmp_path):
    res, fe = structure_run
    lms = [lm for lm in res.results["graph"].landmarks if lm.kind == "structure"]
    assert lms and {lm.model for lm in lms} <= {"manifold", "plet"}
    for lm in lms:
        T_true = true_structure_pose(mission, lm.model)
        assert np.linalg.norm(lm.pose[:3, 3] - T_true[:3, 3]) < 0.3
    obs = [r.observation for r in res.observations if isinstance(r.observation, StructureObservation)]
    assert len({r.stamp for r in res.observations if isinstance(r.observation, StructureObservation)}) >= 3
    # the summary: a metrics block with the registered structure, a world model and figures
    summary = res.frontend_summaries["sonar"]
    assert summary.section == "sonar"
    for s in summary.metrics["structures"]:
        assert s["model"] in ("manifold", "plet") and s["median_error_m"] < 0.03
    assert summary.metrics["world_model_bytes"] <= 0.01 * summary.metrics["raw_cloud_bytes"]
    assert {"world_model.ply", "figures/sonar_elevation_map.png"} <= set(summary.files)
    assert obs and all(np.all(np.isfinite(o.covariance)) for o in obs)
    # written into an output directory, twice (a rerun merges into figures/ rather than failing)
    from semslam.eval.outputs import build_metrics, write_outputs

    metrics = build_metrics(res, mission.metadata)
    rows = metrics["sonar"]["structures"]
    # every structure the front-end registered is at the right place (issue 21): no false structure,
    # none at the wrong place (a miss and a false structure), and each landmark's model found
    assert not [r for r in rows if r["truth_id"] is None], rows
    assert all(r["found"] for r in rows if r["model"] in {lm.model for lm in lms}), rows
    assert metrics["sonar"]["structures_wrong_place"] == 0 and metrics["sonar"]["structures_false"] == 0
    # each registration names its support (the patches it was fitted to, placed by the final estimate),
    # from which the evaluation reads it relative to the trajectory where it was seen
    graph_at = pose_at(res.results["graph"].trajectory)
    for s in summary.metrics["structures"]:
        assert s["support"] and sum(p["points"] for p in s["support"]) >= 1000
        for p in s["support"]:
            assert np.linalg.norm(np.array(p["T_WB"])[:3, 3] - graph_at(p["stamp"])[:3, 3]) < 0.02
    relative = structure_rows(summary.metrics["structures"], mission.metadata.ground_truth, pose_at(res.truth))
    assert {r["judged"] for r in relative if r["found"]} == {"relative"}
    assert [r["found"] for r in relative if r["truth_id"] is not None] == [
        r["found"] for r in rows if r["truth_id"] is not None
    ]
    assert all(r["relative_position_error_m"] < 0.1 for r in relative if r["found"]), relative
    out = write_outputs(tmp_path / "out", SemslamConfig(), res, metrics)
    assert (out / "world_model.ply").stat().st_size == summary.metrics["world_model_bytes"]
    figures = {"sonar_elevation_map.png", "sonar_world_model.png", "sonar_swath_registration.png"}
    assert {p.name for p in (out / "figures").iterdir()} == figures
    # a second run into the same directory (quick stand-in writers for the same files)
    import dataclasses

    rerun = dataclasses.replace(
        summary,
        files={
            n: (lambda p: (p.parent.mkdir(parents=True, exist_ok=True), p.write_bytes(b"x"))) for n in summary.files
        },
    )
    write_outputs(out, SemslamConfig(), dataclasses.replace(res, frontend_summaries={"sonar": rerun}), metrics)
    assert {p.name for p in (out / "figures").iterdir()} == figures
    assert (out / "figures" / "sonar_world_model.png").read_bytes() == b"x"
