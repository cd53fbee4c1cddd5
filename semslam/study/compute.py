"""One mission of a study, in a process of its own: ``python -m semslam.study.compute STAGE`` with
the :class:`~semslam.study.plan.MissionTask` as JSON on stdin.

Simulates the mission if it is a scenario's (into ``STAGE/mission.bag``, kept with ``--keep-bags``),
reads the bag, compares dr / ekf / graph as ``semslam compare`` does
(:func:`semslam.compare.run_comparison`, spilling into ``STAGE``'s hidden ``.spill``, its results and
report written into ``STAGE``, which is itself the study's transaction), and writes the mission's record
(``study_mission.json``) last: a stage without it is incomplete. GTSAM and Open3D live only here.

Why a process and not the Dask worker itself: a timeout can kill it (a Python thread cannot be
stopped), a crash in native code costs one mission rather than the worker, and the pipeline may
start its front-end processes (a Dask worker is a daemonic process, which may not). It dies with
the worker that started it.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import sys
import threading
import time
from pathlib import Path

from semslam.errors import SemslamError
from semslam.study.plan import MissionTask
from semslam.study.store import RECORD
from semslam.study.summary import mission_summary

BAG = "mission.bag"


def _die_with_parent(poll_s: float = 0.5) -> None:
    """Kill this process group (this process and its front-end workers) when the Dask worker that
    started us is gone (killed, lost): its task is re-run elsewhere, this attempt is an orphan."""
    parent = os.getppid()

    def watch():
        while True:
            time.sleep(poll_s)
            if os.getppid() != parent:
                os.killpg(0, signal.SIGKILL)

    threading.Thread(target=watch, daemon=True, name="die-with-parent").start()


def _mission(task: MissionTask, stage: Path, config):
    """The mission as `semslam compare` would read it: a scenario's is simulated and written to a
    bag first (the bag's messages round some values: reading it back is what makes the study's
    numbers those of `semslam simulate` + `semslam compare`)."""
    from semslam.mission.bag import read_mission

    src = task.source
    if src["kind"] == "bag":
        return read_mission(src["path"], config.reader)
    import yaml

    from semslam.sim.scenarios import scenario, simulate_to_bag

    sim_config = scenario(src["scenario"]).model().model_validate(src["sim_config"])
    (stage / "sim_config.yaml").write_text(yaml.safe_dump(src["sim_config"], sort_keys=False))
    simulate_to_bag(src["scenario"], sim_config, stage / BAG)
    mission = read_mission(stage / BAG, config.reader)
    mission.label = task.mission  # not the stage's path: it is renamed when the mission commits
    return mission


def _drop_bag(stage: Path) -> None:
    for path in stage.glob(BAG + "*"):  # the bag and its sidecar
        shutil.rmtree(path) if path.is_dir() else path.unlink()


def compute(task: MissionTask, stage: Path) -> dict:
    """Compute the mission into ``stage``; returns its record (also written there, last)."""
    from semslam.compare import default_frontends, run_comparison
    from semslam.config import SemslamConfig
    from semslam.eval.gps_reference import HoldOut
    from semslam.eval.outputs import spilling_in_stage, write_results
    from semslam.eval.report import write_report
    from semslam.mission.check import check_mission

    t0 = time.perf_counter()
    config = SemslamConfig.model_validate(task.config)
    mission = _mission(task, stage, config)
    # The same check as `semslam compare`: a refusal is this mission's failure, warnings go to its log.
    check = check_mission(mission, task.frontends or default_frontends(mission.metadata))
    check.raise_if_refused()
    for warning in check.warnings:
        print(f"semslam: warning: {warning}", file=sys.stderr, flush=True)
    t_mission = time.perf_counter() - t0
    # As many front-end workers as the cores the study left this mission (one when it runs one per core).
    hold_out = HoldOut.parse(task.hold_out_gps) if task.hold_out_gps else None
    # The run's spill files in the mission's own stage (on the study's filesystem), removed before it
    # commits; a full disk there is this mission's failure, one line naming its folder.
    with spilling_in_stage(stage, named=Path(task.study_dir) / task.mission):
        result, metrics = run_comparison(
            mission,
            config,
            task.frontends,
            frontend_workers=task.frontend_workers,
            hold_out_gps=hold_out,
            check_warnings=check.warnings,
        )
    write_results(stage, config, result, metrics)
    report = write_report(stage, result, mission.metadata, metrics)
    if not task.keep_bag:
        _drop_bag(stage)
    record = {
        "mission": task.mission,
        "identity": task.identity_hash(),
        "input": task.identity(),
        "reproduce": task.reproduce(),
        "report": str(Path(report).relative_to(stage)) if Path(report).is_relative_to(stage) else str(report),
        "summary": mission_summary(metrics),
        "mission_s": t_mission,
        "compute_s": time.perf_counter() - t0,
        "host": socket.gethostname(),
    }
    (stage / RECORD).write_text(json.dumps(record, indent=1))
    return record


def main(argv: list[str]) -> int:
    _die_with_parent()
    stage = Path(argv[0])
    task = MissionTask.from_dict(json.loads(sys.stdin.read()))
    try:
        compute(task, stage)
    except SemslamError as exc:
        print(f"semslam: error: {exc}", file=sys.stderr, flush=True)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
