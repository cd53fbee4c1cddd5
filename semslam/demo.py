"""`semslam demo`: the default tank mission, simulated once (cached), compared through dr, ekf and graph."""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import time
from pathlib import Path

import semslam
from semslam.config import SemslamConfig


def cache_dir() -> Path:
    """semslam's cache folder: $SEMSLAM_CACHE_DIR, else $XDG_CACHE_HOME/semslam, else ~/.cache/semslam
    (the laser's recogniser keeps its CAD views there too)."""
    if os.environ.get("SEMSLAM_CACHE_DIR"):
        return Path(os.environ["SEMSLAM_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "semslam"


def simulator_fingerprint() -> str:
    """Hash of the simulator's source: a changed simulator never reuses a stale cached mission."""
    h = hashlib.sha1(semslam.__version__.encode())
    root = Path(semslam.__file__).parent
    for f in sorted([*(root / "sim").rglob("*.py"), *(root / "models").rglob("*.py")]):  # models: the scene's parts
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


DEMO_PREFIX = "tank-default-"
STALE_PARTIAL_S = 3600.0  # a half-written mission this old belongs to no running simulation


def demo_mission(progress: bool = False) -> Path:
    """The default tank mission as a ROS 1 bag (~320 MB with its sidecar), simulated on first use
    and cached, keyed by the simulator's source: the mission of an older simulator is removed when
    the current one is in place, so the cache holds one. Written aside and renamed into place, so
    an interrupted simulation never leaves a cut bag that the next demo would read."""
    folder = cache_dir() / "missions"
    path = folder / f"{DEMO_PREFIX}{simulator_fingerprint()}.bag"
    if not path.exists():
        folder.mkdir(parents=True, exist_ok=True)
        if progress:
            print(f"simulating the default tank mission (once; cached as {path})", flush=True)
        _simulate_into(path)
    _remove_stale(folder, keep=path)
    return path


def _simulate_into(path: Path) -> None:
    from semslam.mission.bag import write_mission
    from semslam.sim.config import TankSimConfig
    from semslam.sim.simulate import simulate_tank

    stage = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
    try:
        write_mission(simulate_tank(TankSimConfig()), stage / path.name)
        for f in sorted(stage.iterdir(), key=lambda f: f.name == path.name):  # the bag last: it marks it done
            os.replace(f, path.parent / f.name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _remove_stale(folder: Path, keep: Path) -> None:
    """The missions of other simulator versions (bag and sidecar), and half-written ones left by a
    killed simulation."""
    now = time.time()
    for f in folder.iterdir():
        if f.name.startswith(DEMO_PREFIX) and not f.name.startswith(keep.name) and f.is_file():
            f.unlink(missing_ok=True)
        elif f.name.startswith(f".{DEMO_PREFIX}") and f.name.endswith(".partial"):
            if now - f.stat().st_mtime > STALE_PARTIAL_S:
                shutil.rmtree(f, ignore_errors=True)


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
    from semslam.eval.outputs import staged_output, write_staged
    from semslam.eval.replay import make_recorder
    from semslam.mission.bag import read_mission
    from semslam.pipeline import observed_by

    out = Path(out or default_out_dir())
    # The output opened first: its path checked before any work, the run's spill files on its filesystem.
    with staged_output(out, overwrite) as stage:
        cfg = demo_config()
        path = demo_mission(progress)
        mission = read_mission(path, cfg.reader)
        recorder = make_recorder(record, mission.metadata, record_points)
        t0 = time.perf_counter()
        with observed_by(*([recorder] if recorder is not None else [])):
            result, metrics = run_comparison(mission, cfg, progress=progress)
        write_staged(stage, cfg, result, metrics, mission.metadata, report=True, recorder=recorder)
    metrics["wall_time_s"] = time.perf_counter() - t0
    return metrics, out
