"""The promotion of tentative objects on the pipeline (issue 22, stop 40): each object track near a
true object, view by view (its views, and the scans counted with its place in view, which
``association.object_view_ratio`` weighs), under main's "in view" (any scan that saw something within
``object_view_reach_m``) and the sensor-view rule (the place also inside the sensor's view,
``association.object_view_margin_m``), with the map scores of both.

Replays the laser observations that ``experiments/laser_real_eval.py pipeline --dump DIR`` recorded
(graph and EKF, as ``confirm_trace.py``); ``--dump`` may hold ``{seed}`` for one directory a seed.

    python experiments/laser/promotion_trace.py --seeds 19,24 --dump /tmp/s40/laser/rep{seed} [--tracks]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE.parent / "estimators"), str(HERE)]

from confirm_trace import run  # noqa: E402
from laser_real_eval import map_scores, parse_seeds  # noqa: E402


def main() -> None:
    from semslam.mapping import tracks

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--dump", required=True)
    ap.add_argument("--tracks", action="store_true", help="each view of an object track within 0.5 m of a true object")
    args = ap.parse_args()
    note_scan, extend = tracks.TrackSet.note_scan, tracks.TrackSet.extend
    log: list[str] = []
    state = {"objects": np.zeros((0, 3)), "t0": 0}

    def main_rule(self, stamp, points, segments, in_sight=None):
        return note_scan(self, stamp, points, segments)

    def logging_extend(self, views, separators):
        went, promoted = extend(self, views, separators)
        for v, tr in zip(views, went):
            if tr.kind != "object":
                continue
            d = np.linalg.norm(state["objects"] - v.position, axis=1)
            if len(d) and d.min() < 0.5:
                up = " promoted" if any(tr is p for p in promoted) else ""
                log.append(
                    f"    {(v.stamp - state['t0']) * 1e-9:6.1f} s track {tr.key} (true object {int(np.argmin(d))}, "
                    f"{d.min():.2f} m): views {len(tr.views)}, in view {tr.in_view}{up}"
                )
        return went, promoted

    tracks.TrackSet.extend = logging_extend
    for seed in parse_seeds(args.seeds):
        dump = Path(args.dump.format(seed=seed))
        for rule, scan in (("main", main_rule), ("sensor view", note_scan)):
            tracks.TrackSet.note_scan = scan
            for est in ("graph", "ekf"):
                log.clear()
                from pipeline_replay import light_mission

                meta = light_mission(seed, {}, dump).metadata
                truth = meta.ground_truth
                state["objects"] = np.array([o.position for o in truth.objects]).reshape(-1, 3)
                state["t0"] = meta.extras["scans"][0]["stamp"]
                r = run(seed, dump, {}, names=(est,))[0][est]
                sc = map_scores(r.landmarks, truth, meta.extras["scans"])
                errs = sorted(
                    float(np.min(np.linalg.norm(state["objects"] - np.asarray(lm.position), axis=1)))
                    for lm in r.landmarks
                    if lm.kind == "object"
                )
                print(
                    f"seed {seed} {est} {rule}: valves once {sc['valves_mapped_once']}/{sc['valves_seen']} "
                    f"{sc['valve_counts']}, objects {sc['objects_mapped']} ({sc['objects_far_from_any_fitting']} far "
                    f"from a fitting; from the nearest true object {' '.join(f'{e:.3f}' for e in errs)} m), "
                    f"within 5 cm {sc['pipe_within_5cm_share']:.3f}"
                )
                if args.tracks:
                    print("\n".join(log))


if __name__ == "__main__":
    main()
