"""The end-of-mission object confirmation on the pipeline (issue 22, stop 40): which mapped objects
it leaves out under main's "in view" (any scan that saw something within ``object_view_reach_m``)
and the sensor-view rule (``association.object_view_margin_m``), and why each scan counted.

Replays the laser observations that ``experiments/laser_real_eval.py pipeline --dump DIR`` recorded
(graph and EKF, as ``pipeline_replay.py``) once per rule; the confirmation only filters the final
map, so both maps hold the same landmarks. ``--scans`` lists, per mapped object, each scan counted
in view under main's rule: seen or not, the range and the angles (deg) of its place from the
sensor's axis with the true pose (the stereo frame is ±10° × ±7.5°), whether the sensor-view rule
counts it, and the pipe segments within reach (distance, where along the segment, its length).

    python experiments/laser/confirm_trace.py --seeds 24,19 --dump DIR [--scans]
"""

from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE.parent / "estimators"), str(HERE)]

from laser_real_eval import map_scores, parse_seeds  # noqa: E402
from pipeline_replay import light_mission, true_poses  # noqa: E402
from replay_study import RecordedFrontend  # noqa: E402

RULES = {"main": {"association": {"object_view_margin_m": None}}, "sensor view": {}}


class Recorder:
    """Each scan's in-view test of each mapped object, by estimator (wraps InView.scan)."""

    def __init__(self):
        from semslam.mapping import builder, visibility

        self.rows: dict[str, dict[int, list]] = {}
        self.stamp = 0
        self.name = ""
        rec = self
        scan, process = visibility.InView.scan, builder.MapBuilder.process

        def process_(self, stamp, observations):
            rec.stamp = stamp
            return process(self, stamp, observations)

        def scan_(self, ids, positions, points, segments, seen, in_sight=None):
            sight = None if in_sight is None or not len(ids) else in_sight(positions)
            for k, (lid, x) in enumerate(zip(ids, positions, strict=True)):
                if lid not in self.in_view:
                    continue
                segs = []
                for a, b in segments:
                    length = float(np.linalg.norm(b - a))
                    d = float(visibility.point_segment_distance(x[None], a, b)[0])
                    if d < self.reach:
                        segs.append((d, float((x - a) @ (b - a)) / length, length))
                near = len(segs) > 0 or (len(points) and np.linalg.norm(points - x, axis=1).min() < self.reach)
                if near or lid in seen:
                    row = (rec.stamp, lid in seen, None if sight is None else bool(sight[k]), x.copy(), segs)
                    rec.rows.setdefault(rec.name, {}).setdefault(lid, []).append(row)
            return scan(self, ids, positions, points, segments, seen, in_sight)

        builder.MapBuilder.process, visibility.InView.scan = process_, scan_


def run(seed: int, dump: Path, config: dict, names=("graph", "ekf")):
    from semslam.compare import estimators_input
    from semslam.config import SemslamConfig
    from semslam.estimators import create_estimator
    from semslam.pipeline import run_pipeline

    mission = light_mission(seed, {}, dump)
    cfg = SemslamConfig.model_validate(config)
    by_stamp: dict[int, list] = {}
    for rec in pickle.loads((dump / f"pipeline_{seed}.pkl").read_bytes()):
        by_stamp.setdefault(rec.stamp, []).append(rec.observation)
    out = {}
    for name in names:  # one at a time: the recorder knows which estimator's builder calls it
        RECORDER.name = name
        ests = [create_estimator(name, mission.metadata, cfg)]
        fes = [RecordedFrontend("laser", by_stamp, None)]
        res = run_pipeline(estimators_input(mission, cfg), ests, fes, view_estimator=name, frontend_process=False)
        out[name] = res.results[name]
    return out, mission


def describe(lm, truth, rocks) -> str:
    x = np.asarray(lm.position)
    d, tid = min((float(np.linalg.norm(np.asarray(o.position) - x)), o.id) for o in truth.objects)
    rock = float(np.min(np.linalg.norm(rocks[:, :2] - x[:2], axis=1))) if len(rocks) else float("inf")
    return f"id {lm.id}: {d:.3f} m from truth object {tid} ({rock:.2f} m from a rock's centre, horizontally)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--dump", required=True, type=Path)
    ap.add_argument("--scans", action="store_true")
    args = ap.parse_args()
    for seed in parse_seeds(args.seeds):
        maps = {}
        for rule, config in RULES.items():
            RECORDER.rows = {}
            maps[rule], mission = run(seed, args.dump, config)
            rows = RECORDER.rows
        truth = mission.metadata.ground_truth
        rocks = np.array([r["center"] for r in mission.metadata.extras["scene"]["rocks"]]).reshape(-1, 3)
        for est in ("graph", "ekf"):
            for rule, results in maps.items():
                r = results[est]
                sc = map_scores(r.landmarks, truth, mission.metadata.extras["scans"])
                left = r.history.get("objects_left_out") if r.history else None
                print(
                    f"seed {seed} {est} {rule}: valves once {sc['valves_mapped_once']}/{sc['valves_seen']} "
                    f"{sc['valve_counts']}, objects {sc['objects_mapped']} ({sc['objects_far_from_any_fitting']} "
                    f"far from a fitting), left out {left}"
                )
            kept = {lm.id for lm in maps["sensor view"][est].landmarks}
            for lm in maps["sensor view"][est].landmarks:
                if lm.kind == "object":
                    print(f"    {describe(lm, truth, rocks)}{'' if lm.id in kept else ' (left out)'}")
            if not args.scans:
                continue
            pose_at = true_poses(mission)
            for lid, scans in rows.get(est, {}).items():
                print(f"  {est} object {lid}: {len(scans)} scans counted in view by main's rule (after its promotion)")
                for stamp, seen, sight, x, segs in scans:
                    xs = np.linalg.inv(pose_at(stamp)[1]) @ np.r_[x, 1.0]
                    ang = np.degrees(np.arctan2(xs[:2], xs[2]))
                    seg = " ".join(f"[{d:.2f} m, at {t:+.2f}/{n:.2f} m]" for d, t, n in segs)
                    t_s = (stamp - mission.metadata.extras["scans"][0]["stamp"]) * 1e-9
                    print(
                        f"    {t_s:6.1f} s seen {int(seen)} range {xs[2]:.2f} m angles ({ang[0]:+5.1f}, {ang[1]:+5.1f}) "
                        f"sensor view {'-' if sight is None else int(sight)} segments {seg}"
                    )


RECORDER = Recorder()

if __name__ == "__main__":
    main()
