"""What the DVL's dropouts do to the pipeline map (issue 22, stop 40: seed 19's map within 5 cm): the
recorded laser observations (``laser_real_eval.py pipeline --dump DIR``) replayed on the mission as
simulated, and on the same mission with every invalid DVL reading replaced by the last valid one (a
diagnostic, not a remedy: a held velocity is wrong in a turn). Per estimator: the dropouts, the
position error in world x (cm) at a few times, the map within 5 cm and the valves.

    python experiments/laser/dvl_gap_eval.py --seeds 19,24 --dump /tmp/s40/laser/rep{seed}
"""

from __future__ import annotations

import argparse
import dataclasses
import pickle
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE.parent / "estimators"), str(HERE)]

from laser_real_eval import map_scores, parse_seeds  # noqa: E402
from pipeline_replay import light_mission, true_poses  # noqa: E402
from replay_study import RecordedFrontend  # noqa: E402

TIMES_S = (20, 39, 42, 67, 100, 147.5)


def held(items: list) -> tuple[list, int]:
    """The measurements with each invalid DVL reading replaced by the last valid one (and how many)."""
    from semslam.mission.measurements import DvlVelocity

    last, out, n = None, [], 0
    for x in items:
        if isinstance(x, DvlVelocity):
            if x.valid:
                last = x
            elif last is not None:
                x = dataclasses.replace(x, velocity=last.velocity, covariance=last.covariance, valid=True)
                x = dataclasses.replace(x, beam_valid=None)
                n += 1
        out.append(x)
    return out, n


def main() -> None:
    from semslam.compare import estimators_input
    from semslam.config import SemslamConfig
    from semslam.estimators import create_estimator
    from semslam.mission.measurements import DvlVelocity
    from semslam.mission.mission import Mission
    from semslam.pipeline import run_pipeline

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--dump", required=True)
    args = ap.parse_args()
    cfg = SemslamConfig()
    for seed in parse_seeds(args.seeds):
        dump = Path(args.dump.format(seed=seed))
        base = light_mission(seed, {}, dump)
        meta, items = base.metadata, list(base)
        t0 = meta.extras["scans"][0]["stamp"]
        by_stamp: dict[int, list] = {}
        for rec in pickle.loads((dump / f"pipeline_{seed}.pkl").read_bytes()):
            by_stamp.setdefault(rec.stamp, []).append(rec.observation)
        gaps = np.array([(x.stamp - t0) * 1e-9 for x in items if isinstance(x, DvlVelocity) and not x.valid])
        runs = np.split(gaps, np.where(np.diff(gaps) > 0.5)[0] + 1) if len(gaps) else []
        print(f"seed {seed}: DVL dropouts (s) {', '.join(f'{r[0]:.1f}-{r[-1]:.1f}' for r in runs)}")
        for fill in (False, True):
            its, n = held(items) if fill else (items, 0)
            mission = Mission.from_measurements(meta, its)
            pose_at = true_poses(mission)
            for name in ("graph", "ekf"):
                est = create_estimator(name, meta, cfg)
                fes = [RecordedFrontend("laser", by_stamp, None)]
                res = run_pipeline(
                    estimators_input(mission, cfg), [est], fes, view_estimator=name, frontend_process=False
                ).results[name]
                tr = res.trajectory
                errs = []
                for ts in TIMES_S:
                    i = int(np.argmin(np.abs(tr.stamps - (t0 + int(ts * 1e9)))))
                    errs.append(f"{ts:g}:{100 * (tr.positions[i, 0] - pose_at(int(tr.stamps[i]))[0][0, 3]):+.1f}")
                sc = map_scores(res.landmarks, meta.ground_truth, meta.extras["scans"])
                print(
                    f"  {name} {'dropouts held' if fill else 'as simulated'} ({n} readings held): x error cm "
                    f"{' '.join(errs)}; within 5 cm {sc['pipe_within_5cm_share']:.3f}; valves once "
                    f"{sc['valves_mapped_once']}/{sc['valves_seen']} {sc['valve_counts']}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
