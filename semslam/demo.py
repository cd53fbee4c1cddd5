"""`semslam demo`: the default tank mission, simulated once (cached), compared through dr, ekf and graph."""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

import semslam
from semslam.config import SemslamConfig


def cache_dir() -> Path:
    base = os.environ.get("SEMSLAM_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"), "semslam"
    )
    return Path(base)


def simulator_fingerprint() -> str:
    """Hash of the simulator's source: a changed simulator never reuses a stale cached mission."""
    h = hashlib.sha1(semslam.__version__.encode())
    root = Path(semslam.__file__).parent
    for f in sorted([*(root / "sim").rglob("*.py"), *(root / "models").rglob("*.py")]):  # models: the scene's parts
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def demo_mission(progress: bool = False) -> Path:
    """The default tank mission as a ROS 1 bag, simulated on first use and cached."""
    from semslam.mission.bag import write_mission
    from semslam.sim.config import TankSimConfig
    from semslam.sim.simulate import simulate_tank

    path = cache_dir() / "missions" / f"tank-default-{simulator_fingerprint()}.bag"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        if progress:
            print("simulating the default tank mission (once; cached in", path.parent, ")", flush=True)
        write_mission(simulate_tank(TankSimConfig()), path)
    return path


def default_out_dir() -> Path:
    return Path("runs") / time.strftime("demo-%Y%m%d-%H%M%S")


def demo_config() -> SemslamConfig:
    """The defaults, plus what a user of the tank knows: its PVC pipes' radius (a prior for the
    laser front-end's cylinder fit)."""
    from semslam.sim.config import TankSimConfig

    radius = TankSimConfig().structure.pipe_radius_m
    return SemslamConfig(frontends={"laser": {"pipes": {"radius_prior": radius}}})


def run_demo(
    out: Path | None = None,
    progress: bool = False,
    record: bool = True,
    overwrite: bool = False,
    record_points: int | None = None,
):
    """Compare dr, ekf and graph on the default tank mission into ``out``; with ``record`` (the
    default) the run's replay too. Returns metrics.json's content (plus the wall time) and the
    output directory."""
    from semslam.compare import run_comparison
    from semslam.eval.outputs import check_output_dir, write_run
    from semslam.eval.replay import make_recorder
    from semslam.mission.bag import read_mission
    from semslam.pipeline import observed_by

    out = check_output_dir(out or default_out_dir(), overwrite)
    cfg = demo_config()
    path = demo_mission(progress)
    mission = read_mission(path, cfg.reader)
    recorder = make_recorder(record, mission.metadata, record_points)
    t0 = time.perf_counter()
    with observed_by(*([recorder] if recorder is not None else [])):
        result, metrics = run_comparison(mission, cfg, progress=progress)
    write_run(out, cfg, result, metrics, mission.metadata, overwrite=overwrite, report=True, recorder=recorder)
    metrics["wall_time_s"] = time.perf_counter() - t0
    return metrics, out
