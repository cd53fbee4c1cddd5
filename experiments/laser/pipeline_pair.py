"""Both estimators' pipeline maps on recorded laser observations (issue 22, stop 46): the observations
that ``experiments/laser_real_eval.py pipeline --dump DIR`` recorded, replayed through dead reckoning,
the graph and the EKF on the same mission (simulated again, as ``pipeline_replay.py``), each map scored
as ``laser_real_eval.py`` scores the graph's. Run it with two codes on one recording for a paired
comparison of their map building (the front-end is not run).

    python experiments/laser/pipeline_pair.py --seeds 9,11 --dump DIR [--json OUT] [--config JSON]
"""

from __future__ import annotations

import json
import pickle
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE.parent / "estimators"), str(HERE)]

from laser_real_eval import map_scores, parse_seeds  # noqa: E402
from pipeline_replay import light_mission, replay_arguments  # noqa: E402
from replay_study import RecordedFrontend  # noqa: E402

COLUMNS = (
    "pipes_mapped",
    "pipe_error_median_m",
    "pipe_error_p95_m",
    "pipe_within_5cm_share",
    "seen_pipe_length_covered",
    "valves_mapped_once",
    "valves_seen",
    "other_fittings_mapped_once",
    "other_fittings_seen",
    "objects_mapped",
    "pipe_error_max_m",
    "objects_far_from_any_fitting",
    "seen_pipes",
    "mapped_pipes",
    "valve_counts",
    "other_fitting_counts",
)


def replay_both(seed: int, dump: Path, sim: dict, config: dict) -> dict:
    """Each estimator's map scores (graph, EKF) on ``seed``'s recording."""
    from semslam.compare import estimators_input
    from semslam.config import SemslamConfig
    from semslam.estimators import create_estimator
    from semslam.pipeline import run_pipeline

    mission = light_mission(seed, sim, dump)
    cfg = SemslamConfig.model_validate(config)
    by_stamp: dict[int, list] = {}
    for rec in pickle.loads((dump / f"pipeline_{seed}.pkl").read_bytes()):
        by_stamp.setdefault(rec.stamp, []).append(rec.observation)
    fes = [RecordedFrontend("laser", by_stamp, None)]
    ests = [create_estimator(n, mission.metadata, cfg) for n in ("dr", "graph", "ekf")]
    result = run_pipeline(estimators_input(mission, cfg), ests, fes, view_estimator="graph", frontend_process=False)
    meta = mission.metadata
    out = {}
    for name in ("graph", "ekf"):
        scores = map_scores(result.results[name].landmarks, meta.ground_truth, meta.extras["scans"])
        out[name] = {k: scores.get(k) for k in COLUMNS}
    return out


def main(argv=None) -> int:
    ap = replay_arguments(__doc__.splitlines()[0], "34")
    args = ap.parse_args(argv)
    out = {}
    for seed in parse_seeds(args.seeds):
        out[seed] = r = replay_both(seed, args.dump, json.loads(args.sim), json.loads(args.config))
        for name, m in r.items():
            print(
                f"seed {seed} {name}: pipes {m['pipes_mapped']}, error median {m['pipe_error_median_m']:.4f} p95 "
                f"{m['pipe_error_p95_m']:.4f} m, within 5 cm {m['pipe_within_5cm_share']:.3f}, covered "
                f"{m['seen_pipe_length_covered']:.3f}, valves once {m['valves_mapped_once']}/{m['valves_seen']}, "
                f"fittings once {m['other_fittings_mapped_once']}/{m['other_fittings_seen']}, objects "
                f"{m['objects_mapped']}",
                flush=True,
            )
        if args.json is not None:
            args.json.write_text(json.dumps(out, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
