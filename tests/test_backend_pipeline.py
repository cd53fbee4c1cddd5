"""The graph estimator through the project's pipeline and output writer (what ``semslam run
MISSION --estimator graph --frontends oracle --out DIR`` does), on a short synthetic mission."""

import json

import numpy as np

from semslam.config import SemslamConfig
from semslam.estimators import create_estimator
from semslam.eval.outputs import build_metrics, write_outputs
from semslam.pipeline import run_pipeline
from semslam.registry import create_frontends
from tests.support.synthetic_mission import SyntheticConfig, simulate

KEYS = (
    "ate_rmse_m",
    "ate_max_m",
    "rpe_rmse_m",
    "landmark_median_error_m",
    "n_objects",
    "n_pipes",
    "n_structures",
    "runtime_s",
    "update_ms_median",
    "update_ms_p95",
    "nees_mean",
)


def test_graph_run_writes_outputs_with_metric_keys_filled(tmp_path):
    mission = simulate(SyntheticConfig(duration_s=100.0, dropouts=((40.0, 10.0),), ahrs_yaw_bias_rad=0.0, seed=4))
    cfg = SemslamConfig()
    est = create_estimator("graph", mission.metadata, cfg)
    fes = create_frontends(["oracle"], mission.metadata, cfg.frontends)
    pr = run_pipeline(mission, [est], fes)
    metrics = build_metrics(pr, mission.metadata)
    out = write_outputs(tmp_path / "run", cfg, pr, metrics)
    for name in ("graph", "graph_online"):
        block = json.loads((out / "metrics.json").read_text())["estimators"][name]
        assert all(block[k] is not None for k in KEYS), {k: block[k] for k in KEYS}
        assert block["ate_rmse_m"] < 0.1 and 0.5 < block["nees_mean"] < 10
        assert (out / f"trajectory_{name}.tum").is_file()
    assert (out / "map_graph.json").is_file() and (out / "map_graph.ply").is_file()
    tum = np.loadtxt(out / "trajectory_graph.tum")
    assert tum.shape[1] == 8 and len(tum) >= 100
    # config.yaml is the resolved configuration: the front-end's section with its defaults filled in
    import yaml

    written = yaml.safe_load((out / "config.yaml").read_text())
    assert cfg.frontends.get("oracle") is None
    assert written["frontends"]["oracle"] == fes[0].config.model_dump(mode="json")
    assert "miss_rate" in written["frontends"]["oracle"]
