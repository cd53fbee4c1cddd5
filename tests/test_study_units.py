"""The study's parts that need no cluster: seeds, tasks as plain data, statistics, user errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.cli import app
from semslam.errors import ConfigError
from semslam.study.cluster import frontend_workers_per_mission, local_workers
from semslam.study.plan import MissionTask, parse_seeds, scenario_tasks
from semslam.study.report import write_study_report
from semslam.study.stats import bootstrap_ci, distribution, paired_ratio, study_statistics
from semslam.study.summary import mission_summary
from semslam.study.task import run_mission

runner = CliRunner()


def test_parse_seeds():
    assert parse_seeds("0-3") == [0, 1, 2, 3]
    assert parse_seeds("7, 0-2,1") == [7, 0, 1, 2]
    for bad in ("3-1", "a", "1-", ""):
        with pytest.raises(ConfigError, match="--seeds"):
            parse_seeds(bad)


def test_tasks_are_plain_data_with_resolved_configs(tmp_path):
    """What a Dask task gets survives JSON unchanged: paths, a seed, configurations as mappings,
    the simulator's resolved (so its drawn world is fixed on the client) and validated."""
    from semslam.sim.config import TankSimConfig

    tasks = scenario_tasks(tmp_path, "tank", [0, 5], ("noise",), {"graph": {}})
    for t in tasks:
        assert json.loads(json.dumps(t.to_dict())) == t.to_dict()
    seed0, seed5 = (TankSimConfig.model_validate(t.source["sim_config"]) for t in tasks)
    assert seed0 == TankSimConfig()  # seed 0: the default mission
    assert seed5.seed == 5 and seed5.dvl.sigma_m_s != TankSimConfig().dvl.sigma_m_s
    assert seed5.structure == TankSimConfig().structure  # only the noise varies
    assert tasks[0].identity_hash() != tasks[1].identity_hash()
    bad = tmp_path / "sim.yaml"
    bad.write_text("dvl: {sigma_m_s: -1}\n")
    with pytest.raises(ConfigError, match=r"sim.yaml: dvl.sigma_m_s"):
        scenario_tasks(tmp_path, "tank", [1], (), {}, bad)


def test_distribution_skips_missing_values():
    d = distribution([1.0, None, 3.0, float("nan"), 2.0])
    assert (d["n"], d["median"], d["min"], d["max"], d["mean"]) == (3, 2.0, 1.0, 3.0, 2.0)
    assert d["values"] == [1.0, None, 3.0, None, 2.0]
    assert distribution([None])["median"] is None


def test_paired_ratio_pairs_by_mission():
    r = paired_ratio([1.0, 4.0, None, 2.0, 0.0], [2.0, 2.0, 1.0, None, 1.0])
    assert r["values"] == [0.5, 2.0, None, None, None] and r["n"] == 2
    assert r["median"] == pytest.approx(1.25) and r["geomean"] == pytest.approx(1.0) and r["share_below_1"] == 0.5
    same = paired_ratio([1.0, 2.0, 3.0], [2.0, 4.0, 6.0])
    assert same["median_ci95"] == [0.5, 0.5] and same["geomean_ci95"] == [0.5, 0.5]
    assert paired_ratio([1.0], [2.0])["median_ci95"] is None  # one pair: no interval


def test_bootstrap_interval_covers_the_true_median():
    """Over many samples of 25 log-normal ratios, the 95 % interval of the median holds the true
    median about 95 % of the time (bootstrap intervals run a little narrow on small samples)."""
    rng = np.random.default_rng(1)
    true = np.exp(-0.7)  # a graph/EKF ratio of ~0.5
    hits = 0
    for _ in range(80):
        x = np.exp(rng.normal(-0.7, 0.5, 25))
        lo, hi = bootstrap_ci(x, lambda v, axis=-1: np.median(v, axis=axis))
        hits += lo <= true <= hi
    assert 0.85 <= hits / 80 <= 1.0


def test_study_statistics_per_estimator_and_pair():
    def summary(dr, ekf, graph, f1):
        est = {n: {"ate_rmse_m": v, "runtime_s": 1.0} for n, v in (("dr", dr), ("ekf", ekf), ("graph", graph))}
        return {"estimators": est, "recognition_f1": {"SEM": f1}}

    s = study_statistics([summary(1.0, 0.5, 0.25, 0.8), None, summary(2.0, 1.0, 0.4, 0.6)])
    assert s["distributions"]["graph"]["ate_rmse_m"]["values"] == [0.25, None, 0.4]
    assert s["distributions"]["dr"]["nees_mean"]["n"] == 0
    assert s["recognition"]["SEM"]["f1"]["median"] == pytest.approx(0.7)
    assert s["ratios"]["graph/ekf"]["ate_rmse_m"]["values"] == [0.5, None, 0.4]
    assert s["ratios"]["ekf/dr"]["ate_rmse_m"]["median"] == 0.5
    assert s["ratios"]["graph/dr"]["ate_rmse_m"]["values"] == [0.25, None, 0.2]
    assert set(s["ratios"]) == {"graph/ekf", "ekf/dr", "graph/dr"}


def test_shares_and_seen_pipe_ratios_per_mission():
    def metrics(once, dup, missed):
        e = {"objects_once": once, "nees_in_band": True, "pipe_seen": 20, "pipe_missed": missed, "pipe_duplicates": dup}
        return {"mission": {"gt_pipes": 25}, "estimators": {"graph": e}}

    rows = [mission_summary(metrics(*a)) for a in ((True, 0, 1), (False, 2, 0), (True, 0, 0))]
    assert rows[0]["estimators"]["graph"]["pipes_seen_mapped_ratio"] == pytest.approx(0.95)
    assert rows[1]["estimators"]["graph"]["pipe_duplicate_ratio"] == pytest.approx(0.1)
    s = study_statistics(rows + [None])
    assert s["shares"]["graph"]["objects_once"] == {"n": 3, "share": pytest.approx(2 / 3)}
    assert s["distributions"]["graph"]["pipes_seen_mapped_ratio"]["min"] == pytest.approx(0.95)


def test_report_shows_shares_and_only_what_missions_have(tmp_path):
    """The report's tables: the shares of missions (objects once), labelled; no row for a metric no
    mission has (here: no landmark error, no GPS reference), no raw key where a label exists."""
    est = {"ate_rmse_m": 0.1, "ate_rmse_pos_yaw_m": 0.05, "objects_once": True, "object_duplicates": 0}
    rows = [{"estimators": {"graph": dict(est, objects_once=o), "ekf": est}, "recognition_f1": {}} for o in (1, 1, 0)]
    counts = {"planned": 3, "ok": 3, "failed": 0, "timeout": 0, "not_run": 0}
    study = {"study": {"title": "t"}, "counts": counts, "missions": [], "worst": [], "failures": []}
    page = write_study_report(tmp_path, {**study, **study_statistics(rows)}).read_text()
    assert "graph</td><td>every object mapped exactly once</td><td>3</td><td>0.667" in page
    assert "objects mapped twice" in page and "position+yaw alignment" in page
    assert "landmark median error" not in page and "held-out GPS" not in page
    assert "ate_rmse_pos_yaw_m" not in page


@pytest.mark.parametrize(
    "args, message",
    [
        (["--out", "o"], "either bags or --scenario"),
        (["m.bag", "--scenario", "tank", "--out", "o"], "either bags or --scenario"),
        (["--scenario", "tank", "--seeds", "x", "--out", "o"], "--seeds"),
        (["--scenario", "tank", "--vary", "colour", "--out", "o"], "--vary: unknown aspect 'colour'"),
        (["--scenario", "pond", "--out", "o"], "unknown scene 'pond'"),
        (["missing.bag", "--out", "o"], "missing.bag: no such bag"),
        (["--scenario", "tank", "--timeout", "0", "--out", "o"], "--timeout"),
        (["--scenario", "dive", "--hold-out-gps", "every:1", "--out", "o"], "--hold-out-gps 'every:1'"),
    ],
)
def test_user_errors_are_one_line(tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(app, ["study", *args])
    assert res.exit_code == 1 and message in res.output, res.output
    assert len([line for line in res.output.splitlines() if line.strip()]) == 1
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("cores, workers, expected", [(2, 2, 1), (2, 1, 2), (8, 2, 4), (8, 3, 2), (8, None, 1)])
def test_a_mission_gets_the_cores_the_local_cluster_leaves_it(monkeypatch, cores, workers, expected):
    """`--workers 1` on a 2-core machine: the mission's front-ends in two processes, as in `compare`;
    one mission per core: one each; a user's cluster (None): one each (a worker is one core)."""
    monkeypatch.setattr("os.cpu_count", lambda: cores)
    assert frontend_workers_per_mission(workers) == expected


@pytest.mark.parametrize(
    "cores, requested, tasks, expected",
    [(2, None, 20, 1), (8, None, 20, 4), (8, None, 3, 3), (2, 5, 20, 2), (1, None, 4, 1)],
)
def test_local_cluster_default_is_one_mission_per_two_cores(monkeypatch, cores, requested, tasks, expected):
    """A mission keeps ~2 cores busy (its front-ends run apart): by default one per two cores, never
    more workers than cores or missions."""
    monkeypatch.setattr("os.cpu_count", lambda: cores)
    assert local_workers(requested, tasks) == expected


def test_a_missions_child_computes_with_the_workers_semslam_not_a_checkout_in_the_current_directory(
    tmp_path, monkeypatch
):
    """A semslam checkout in the current directory (another version, a copy kept for a paired run) does
    not compute the study's missions: `python -m` would put it first on the child's path. Here it
    would exit at once; the worker's own semslam gets to the mission and fails on its missing bag."""
    shadow = tmp_path / "cwd" / "semslam"
    shadow.mkdir(parents=True)
    (shadow / "__init__.py").write_text('raise SystemExit("the semslam of the current directory")\n')
    monkeypatch.chdir(tmp_path / "cwd")
    bag = tmp_path / "gone.bag"
    task = MissionTask("m", str(tmp_path / "study"), {"kind": "bag", "path": str(bag)}, {})
    out = run_mission(task.to_dict())
    assert out["status"] == "failed"
    assert "current directory" not in out["failure"]["error"], out["failure"]
    assert "gone.bag" in out["failure"]["error"], out["failure"]
