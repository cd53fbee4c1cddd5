"""`semslam study` on real Dask clusters: short simulated tank missions (oracle front-end), compared
against the same missions run one after the other with `semslam simulate` + `semslam compare`.

A LocalCluster of 2 workers (interrupted, then resumed), a `dask scheduler` with two `dask worker`
processes (one killed mid-study), a study of bags with a broken one, and a timeout.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import pytest
from typer.testing import CliRunner

from semslam.cli import app

runner = CliRunner()
# Three missions: two workers busy at once and one more waiting, so that an interruption after the
# first finished mission leaves some done and some not, and the paired ratios have several pairs.
# (Four made the same points; each mission costs ~15 s of CPU, and this module was 21 % of the suite.)
SEEDS = (0, 1, 2)
SHORT_SIM = "trajectory: {duration_s: 20.0, rest_s: 1.0, ramp_s: 6.0, loops: 0.2}\nlaser: {resolution: [40, 30]}\n"
TIMING_KEYS = {"runtime_s", "update_ms_median", "update_ms_p95", "timing_s", "wall_time_s"}
DASK = Path(sys.executable).with_name("dask")


def numbers(metrics: dict):
    """metrics.json without its timings and with its warnings' file names left out (each names the
    bag it ran on: the study's own copy, or the user's): what must not depend on where a mission ran."""
    if isinstance(metrics, dict):
        out = {k: numbers(v) for k, v in metrics.items() if k not in TIMING_KEYS}
        if isinstance(out.get("warnings"), list):
            out["warnings"] = [w.split(": ", 1)[-1] for w in out["warnings"]]
        return out
    if isinstance(metrics, list):
        return [numbers(v) for v in metrics]
    return metrics


def study_numbers(out: Path) -> dict:
    return {d.name: numbers(json.loads((d / "metrics.json").read_text())) for d in out.glob("tank-seed*")}


def mtimes(folder: Path) -> dict:
    return {p: p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


def compute_processes(out: Path) -> list[psutil.Process]:
    """The missions' compute processes of the study in ``out`` still alive."""
    found = []
    for p in psutil.process_iter(["cmdline"]):
        cmd = " ".join(p.info["cmdline"] or [])
        if "semslam.study.compute" in cmd and str(out) in cmd:
            found.append(p)
    return found


def wait_for(condition, timeout_s: float, what: str):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        value = condition()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict:
    d = tmp_path_factory.mktemp("study-inputs")
    (d / "short.yaml").write_text(SHORT_SIM)
    (d / "semslam.yaml").write_text("{}\n")  # the defaults, for the study and the serial runs alike
    return {"dir": d, "sim": d / "short.yaml", "config": d / "semslam.yaml"}


def study_args(inputs, out: Path, *extra: str) -> list[str]:
    return ["study", "--frontends", "oracle", "--config", str(inputs["config"]), "--out", str(out), *extra]


def scenario_args(inputs, out: Path, *extra: str, seeds: tuple[int, ...] = SEEDS) -> list[str]:
    span = f"{seeds[0]}-{seeds[-1]}"
    return study_args(inputs, out, "--scenario", "tank", "--seeds", span, "--sim-config", str(inputs["sim"]), *extra)


@pytest.fixture(scope="module")
def serial(inputs) -> dict:
    """Each mission simulated and compared by the commands a user would type, one after the other."""
    out = {}
    for seed in SEEDS:
        bag = inputs["dir"] / f"tank-seed{seed}.bag"
        res = runner.invoke(
            app, ["simulate", "tank", "--seed", str(seed), "--sim-config", str(inputs["sim"]), "--out", str(bag)]
        )
        assert res.exit_code == 0, res.output
        cmp_dir = inputs["dir"] / f"compare-seed{seed}"
        res = runner.invoke(
            app,
            ["compare", str(bag), "--frontends", "oracle", "--config", str(inputs["config"]), "--out", str(cmp_dir)],
        )
        assert res.exit_code == 0, res.output
        out[f"tank-seed{seed}"] = {"bag": bag, "numbers": numbers(json.loads((cmp_dir / "metrics.json").read_text()))}
    return out


def test_local_cluster_interrupted_then_resumed(inputs, serial, tmp_path):
    """Interrupted after its first mission, the study keeps what finished; re-run, it computes only
    the rest (the finished missions' files untouched) and every number is the serial run's."""
    out = tmp_path / "study"
    cmd = [sys.executable, "-m", "semslam.cli", *scenario_args(inputs, out, "--workers", "2")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        first = wait_for(lambda: list(out.glob("tank-seed*/study_mission.json")), 600, "a finished mission")
        proc.send_signal(signal.SIGINT)
        output = proc.communicate(timeout=120)[0].decode()
    finally:
        proc.kill()
    assert proc.returncode == 130, output
    wait_for(lambda: not compute_processes(out), 30, "the interrupted missions' processes to end")
    done = {p.parent.name for p in out.glob("tank-seed*/study_mission.json")}
    partial = json.loads((out / "study.json").read_text())  # what finished, even while shutting down
    assert {m["mission"] for m in partial["missions"] if m["status"] == "ok"} == done, partial["counts"]
    assert {p.parent.name for p in first} <= done and len(done) < len(SEEDS)
    assert {m["status"] for m in partial["missions"] if m["mission"] not in done} == {"not_run"}
    assert not list((out / ".study").glob("staging/*"))  # nothing half-done left behind
    before = {name: mtimes(out / name) for name in done}

    res = runner.invoke(app, scenario_args(inputs, out, "--workers", "2"))
    assert res.exit_code == 0, res.output
    study = json.loads((out / "study.json").read_text())
    n = len(SEEDS)
    assert study["counts"] == {"planned": n, "ok": n, "failed": 0, "timeout": 0, "not_run": 0}
    assert {name: mtimes(out / name) for name in done} == before  # not recomputed
    assert [m["reused"] for m in study["missions"]] == [m["mission"] in done for m in study["missions"]]
    assert study_numbers(out) == {name: s["numbers"] for name, s in serial.items()}
    assert not list((out / ".study").glob("staging/*"))
    assert not list(out.glob("tank-*/.*"))  # each mission spilled into its stage's .spill, removed before it committed
    # A simulated mission's warnings name the mission, not its bag in the stage (gone once committed).
    warned = {
        d.name: json.loads((d / "metrics.json").read_text())["input"].get("warnings", []) for d in out.glob("tank-*")
    }
    assert any(warned.values()), warned  # seed 1 starts without bottom lock
    assert all(w.startswith(f"{name}: ") for name, ws in warned.items() for w in ws), warned

    # study.json: per mission in seed order, distributions and paired ratios over all of them
    assert [m["mission"] for m in study["missions"]] == [f"tank-seed{s}" for s in SEEDS]
    graph_ate = [
        json.loads((out / m / "metrics.json").read_text())["estimators"]["graph"]["ate_rmse_m"] for m in serial
    ]
    assert study["distributions"]["graph"]["ate_rmse_m"]["values"] == graph_ate
    ratio = study["ratios"]["graph/ekf"]["ate_rmse_m"]
    ekf_ate = study["distributions"]["ekf"]["ate_rmse_m"]["values"]
    assert ratio["values"] == pytest.approx([g / e for g, e in zip(graph_ate, ekf_ate)])
    assert ratio["n"] == n and ratio["median_ci95"][0] <= ratio["median"] <= ratio["median_ci95"][1]
    # the report opens with the ratios and distributions, figures embedded, worst missions linked
    page = (out / "report.html").read_text()
    assert page.index("Paired ratios") < page.index("Distributions") < page.index("Worst missions")
    assert page.count("data:image/png;base64,") >= 2
    assert study["worst"][0]["ate_rmse_m"] == max(graph_ate)
    for w in study["worst"]:
        assert f"href='{w['report']}'" in page and (out / w["report"]).is_file()


def _written_address(sched_file) -> str | None:
    """The scheduler's address once its file is whole: the scheduler creates the file before it writes it,
    so it may exist empty or half-written for a moment."""
    try:
        return json.loads(sched_file.read_text())["address"]
    except (OSError, ValueError, KeyError):
        return None


@pytest.fixture
def dask_cluster(tmp_path):
    """A `dask scheduler` and two `dask worker` processes (one thread each) on localhost, stopped
    (with whatever they started) when the test ends, pass or fail."""
    sched_file = tmp_path / "scheduler.json"
    procs = []

    def start(*args):
        procs.append(
            subprocess.Popen(
                [str(DASK), *args], start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
            )
        )

    try:
        start("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--scheduler-file", str(sched_file))
        address = wait_for(lambda: _written_address(sched_file), 60, "the scheduler")
        for name in ("w1", "w2"):
            start("worker", "--scheduler-file", str(sched_file), "--nthreads", "1", "--no-dashboard", "--name", name)
        from distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGKILL)  # the nanny, its worker and the missions they run
            except ProcessLookupError:
                pass
            p.wait()


def test_dask_scheduler_and_workers_one_killed(inputs, serial, dask_cluster, tmp_path):
    """On a `dask scheduler` + two `dask worker`s, a worker process killed while it computes a
    mission: Dask runs that mission again, the study finishes whole, with the serial run's numbers."""
    out = tmp_path / "study"
    # Two missions, one per worker: one worker is killed while the other's mission goes on; what is
    # asserted (the killed mission run again, the study whole with the serial numbers) needs no more.
    seeds = SEEDS[:2]
    killed = {}

    def kill_a_busy_worker():
        try:
            child = wait_for(lambda: compute_processes(out), 600, "a mission to start")[0]
            killed["stage"] = next(a for a in child.cmdline() if ".study/staging" in a)
            worker = child.parent()
            killed["worker"] = worker.pid
            worker.kill()
        except Exception as exc:  # reported by the assertion below
            killed["error"] = repr(exc)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    res = runner.invoke(app, scenario_args(inputs, out, "--scheduler", dask_cluster, seeds=seeds))
    killer.join()
    assert "worker" in killed, killed
    assert res.exit_code == 0, res.output
    study = json.loads((out / "study.json").read_text())
    assert study["counts"]["ok"] == len(seeds) and study["study"]["scheduler"] == dask_cluster
    assert study_numbers(out) == {f"tank-seed{s}": serial[f"tank-seed{s}"]["numbers"] for s in seeds}
    rerun = Path(killed["stage"]).name.split(".")[0]  # the mission the killed worker was computing
    assert next(m for m in study["missions"] if m["mission"] == rerun)["status"] == "ok"
    assert not compute_processes(out)  # the killed worker's attempt died with it


@pytest.mark.slow
def test_bags_with_a_broken_one_then_fixed(inputs, serial, tmp_path):
    """A study of bags: the broken one fails with its error and never stops the good one; once
    fixed, a re-run computes it alone. A study folder holding missions of another configuration,
    or in use by another study, is refused."""
    good = serial["tank-seed0"]["bag"]
    broken = tmp_path / "broken.bag"
    broken.write_text("not a bag")
    out = tmp_path / "study"
    args = study_args(inputs, out, str(good), str(broken), "--workers", "2")
    res = runner.invoke(app, args)
    assert res.exit_code == 1, res.output
    study = json.loads((out / "study.json").read_text())
    status = {m["mission"]: (m["status"], m["error"]) for m in study["missions"]}
    assert status["tank-seed0"] == ("ok", None)
    assert status["broken"][0] == "failed" and "broken.bag" in status["broken"][1]
    assert (out / study["failures"][0]["log"]).is_file()
    assert "broken: failed" in res.output
    good_files = mtimes(out / "tank-seed0")

    for f in good.parent.glob(good.name + "*"):  # the bag and its sidecar
        shutil.copyfile(f, tmp_path / f.name.replace(good.name, broken.name))
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    study = json.loads((out / "study.json").read_text())
    assert [(m["mission"], m["status"], m["reused"]) for m in study["missions"]] == [
        ("tank-seed0", "ok", True),
        ("broken", "ok", False),
    ]
    assert study["failures"] == [] and not (out / ".study" / "failed" / "broken.json").exists()
    assert mtimes(out / "tank-seed0") == good_files
    assert numbers(json.loads((out / "broken" / "metrics.json").read_text())) == serial["tank-seed0"]["numbers"]

    other = tmp_path / "other.yaml"
    other.write_text("graph: {window_s: 900.0}\n")
    res = runner.invoke(app, [*args[:4], str(other), *args[5:]])
    assert res.exit_code == 1 and "another source or configuration" in res.output and "tank-seed0" in res.output

    from semslam.study.store import StudyStore

    held = StudyStore(out)
    held.lock()
    try:
        res = runner.invoke(app, args)
        assert res.exit_code == 1 and "another study is running" in res.output
    finally:
        held.unlock()


def test_timeout_is_recorded(inputs, tmp_path):
    out = tmp_path / "study"
    args = study_args(inputs, out, "--scenario", "tank", "--seeds", "1", "--sim-config", str(inputs["sim"]))
    res = runner.invoke(app, [*args, "--timeout", "1", "--workers", "1"])
    assert res.exit_code == 1, res.output
    study = json.loads((out / "study.json").read_text())
    assert study["counts"]["timeout"] == 1 and not (out / "tank-seed1").exists()
    assert study["missions"][0]["error"] == "exceeded the timeout of 1 s"
    assert not compute_processes(out)


@pytest.mark.slow
def test_gps_held_out_in_a_study_as_in_compare(tmp_path):
    """A campaign of real recordings has no ground truth: its reference is the GPS fixes held out.
    A study with --hold-out-gps gives each mission compare's numbers with the same option, and its
    statistics carry the error at the held-out fix."""
    sim = tmp_path / "dive.yaml"
    sim.write_text(
        "trajectory: {lines: 1}\ndive: {surface_start_s: 10.0, surface_end_s: 10.0, descent_s: 10.0, ascent_s: 10.0}\n"
    )
    bag, alone, out = tmp_path / "dive.bag", tmp_path / "compare", tmp_path / "study"
    res = runner.invoke(app, ["simulate", "dive", "--seed", "1", "--sim-config", str(sim), "--out", str(bag)])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["compare", str(bag), "--hold-out-gps", "last", "--out", str(alone)])
    assert res.exit_code == 0, res.output
    args = ["study", "--scenario", "dive", "--seeds", "1", "--sim-config", str(sim), "--hold-out-gps", "last"]
    res = runner.invoke(app, [*args, "--workers", "1", "--out", str(out)])
    assert res.exit_code == 0, res.output
    expected = numbers(json.loads((alone / "metrics.json").read_text()))
    got = numbers(json.loads((out / "dive-seed1" / "metrics.json").read_text()))
    assert expected["reference"] == "gps" and expected["gps_reference"]["n_fixes"] == 1
    assert got == expected
    study = json.loads((out / "study.json").read_text())
    for est in ("ekf", "graph"):
        last = expected["estimators"][est]["gps_error_last_m"]
        assert study["distributions"][est]["gps_error_last_m"]["values"] == [pytest.approx(last)]
    assert study["ratios"]["graph/dr"]["gps_error_last_m"]["n"] == 1
    assert "--hold-out-gps last" in study["missions"][0]["reproduce"]
