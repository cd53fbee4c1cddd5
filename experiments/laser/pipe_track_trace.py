"""A true pipe's line observations followed through the map core (issue 22, stop 44: seed 34's pipe 3
lost): the laser observations that ``experiments/laser_real_eval.py pipeline --dump DIR`` recorded, fed
again to the graph (as ``pipeline_replay.py``), with every event of the map core on the chosen true pipe
logged: each of its line observations (placed with the true pose; after the batch's collinear merge) paired
with a mapped pipe (which, and which true pipe that landmark lies on), judged a mapped landmark seen badly
(χ²-compatible with one, or lying on a mapped pipe's seen stretch) or sent to a tentative track (its views,
promotion); the duplicate merges of pipes; and the map's pipes at the end.

    python experiments/laser/pipe_track_trace.py --seed 34 --pipe 3 --dump DIR [--config JSON] [--sim JSON]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE.parent / "estimators"), str(HERE)]

from laser_real_eval import map_scores  # noqa: E402
from pipeline_replay import light_mission, replay, true_poses  # noqa: E402


def trace(
    seed: int, pipe: int, dump: Path, sim: dict, config: dict, details: bool = False, estimator: str = "graph"
) -> list[str]:
    from frontends.laser.evaluation import matching_pipe
    from semslam.mapping import builder, tracks
    from semslam.mapping.association import chi2_gate
    from semslam.observations import LineObservation

    mission = light_mission(seed, sim, dump)
    truth = mission.metadata.ground_truth
    pose_at = true_poses(mission)
    t0 = mission.metadata.extras["scans"][0]["stamp"]
    log: list[str] = []
    on_truth: dict[int, int | None] = {}  # landmark id → the true pipe its mapped line lies on

    def true_pipe(z: LineObservation) -> int | None:
        T = pose_at(z.stamp)[1]
        P = np.stack([z.p, z.q]) @ T[:3, :3].T + T[:3, 3]
        g = matching_pipe(P[0], P[1], truth.pipes)
        return None if g is None else g.id

    def t(stamp) -> str:
        return f"{(stamp - t0) * 1e-9:6.1f} s"

    def landmark_truth(state, lid) -> str:
        for pid, c, d in state.pipes():
            if pid == lid:
                g = matching_pipe(c - 0.1 * d, c + 0.1 * d, truth.pipes, distance=0.1)
                on_truth[lid] = None if g is None else g.id
        return f"landmark {lid} (on true pipe {on_truth.get(lid)})"

    orig_process, orig_overlaps = builder.MapBuilder.process, builder.MapBuilder._overlaps_mapped
    orig_extend = tracks.TrackSet.extend

    def process(self, stamp, observations):
        if getattr(self.state, "_traced", None) is None:
            update, promote = self.state.update, self.state.promote

            def traced_update(paired):
                for z, lid, _ in paired:
                    if isinstance(z, LineObservation) and true_pipe(z) == pipe:
                        log.append(f"{t(z.stamp)} view {_len(z)} paired with {landmark_truth(self.state, lid)}")
                return update(paired)

            def traced_promote(track):
                lid = promote(track)
                if track.kind == "pipe" and any(true_pipe(v.z) == pipe for v in track.views):
                    log.append(f"{t(track.last_stamp)} track {track.key} PROMOTED to landmark {lid}")
                return lid

            candidates = self.state.candidates

            def traced_candidates(obs, confidence, scan):
                found, ids = candidates(obs, confidence, scan)
                for k, (i, j) in enumerate(zip(found.obs, found.lm)):
                    z = obs[i]
                    if details and isinstance(z, LineObservation) and true_pipe(z) == pipe:
                        gate = chi2_gate(self.assoc.confidence, found.dof(k))
                        log.append(
                            f"        NIS with landmark {ids[j]}: {found.nis[k]:.2f} "
                            f"(gate {gate:.2f} at association.confidence)"
                        )
                return found, ids

            self.state.candidates = traced_candidates
            self.state.update, self.state.promote, self.state._traced = traced_update, traced_promote, True
        n = len(self.diagnostics)
        out = orig_process(self, stamp, observations)
        for line in self.diagnostics[n:]:
            if "are one" in line:
                log.append(f"{t(stamp)} {line}")
        return out

    def overlaps(self, z, mapped_objects, separators, lines):
        hit = orig_overlaps(self, z, mapped_objects, separators, lines)
        if hit and isinstance(z, LineObservation) and true_pipe(z) == pipe:
            log.append(f"{t(z.stamp)} view {_len(z)} lies on a mapped pipe's seen stretch: starts nothing")
        return hit

    def extend(self, views, separators):
        went, promoted = orig_extend(self, views, separators)
        for v, tr in zip(views, went, strict=True):
            if isinstance(v.z, LineObservation) and true_pipe(v.z) == pipe:
                log.append(f"{t(v.stamp)} view {_len(v.z)} to track {tr.key}: views {len(tr.views)}")
        return went, promoted

    orig_excludes = builder.Scan.excludes

    def excludes(self, lid, seg_W, c, d):
        out = orig_excludes(self, lid, seg_W, c, d)
        g = matching_pipe(seg_W[0], seg_W[1], truth.pipes)
        if g is not None and g.id == pipe and details:
            a = self.assoc
            ext = self.book.extent(lid)
            span = ext.interval(c, d, self.cutters, a.inline_object_radius_m)
            s = (seg_W - c) @ d
            r = self.separators - c
            s_obj = r @ d
            on = np.linalg.norm(r - np.outer(s_obj, d), axis=1) < a.inline_object_radius_m
            log.append(
                f"        excludes(landmark {lid}) = {out}: seen {span[0]:.2f}..{span[1]:.2f} "
                f"(outer {ext.outer(c, d)[0]:.2f}..{ext.outer(c, d)[1]:.2f}, {len(ext)} views), segment "
                f"{s.min():.2f}..{s.max():.2f}, objects on the line at {np.round(s_obj[on], 2).tolist()} "
                f"(mapped: {len(self.cutters)})"
            )
        return out

    builder.Scan.excludes = excludes
    builder.MapBuilder.process, builder.MapBuilder._overlaps_mapped = process, overlaps
    tracks.TrackSet.extend = extend
    try:
        results, mission, by_stamp = replay(seed, dump, sim, config, estimator=estimator)
    finally:
        builder.MapBuilder.process, builder.MapBuilder._overlaps_mapped = orig_process, orig_overlaps
        tracks.TrackSet.extend = orig_extend
        builder.Scan.excludes = orig_excludes
    n_obs = sum(1 for obs in by_stamp.values() for z in obs if isinstance(z, LineObservation) and true_pipe(z) == pipe)
    graph = results[estimator]
    scores = map_scores(graph.landmarks, truth, mission.metadata.extras["scans"])
    log.insert(0, f"seed {seed}, true pipe {pipe}: {n_obs} recorded line observations on it")
    for lm in graph.landmarks:
        if lm.kind == "pipe" and lm.p is not None:
            g = matching_pipe(lm.p, lm.q, truth.pipes, distance=0.1)
            log.append(
                f"  map: pipe {lm.id} length {np.linalg.norm(lm.q - lm.p):.2f} m, views {lm.n_observations}, "
                f"on true pipe {None if g is None else g.id}"
            )
    log.append(f"  seen length covered {scores['seen_pipe_length_covered']:.2f}")
    return log


def _len(z) -> str:
    return f"{np.linalg.norm(z.q - z.p):.2f} m"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--pipe", type=int, required=True, help="the true pipe's id")
    ap.add_argument("--dump", type=Path, required=True)
    ap.add_argument("--sim", default="{}", help="pipeline simulator overrides (JSON, nested sections)")
    ap.add_argument("--config", default="{}", help="semslam configuration overrides (JSON)")
    ap.add_argument("--details", action="store_true", help="each exclusion test of a view of the pipe")
    ap.add_argument("--estimator", default="graph", choices=("graph", "ekf"), help="the estimator replayed")
    args = ap.parse_args(argv)
    sim, config = json.loads(args.sim), json.loads(args.config)
    for line in trace(args.seed, args.pipe, args.dump, sim, config, args.details, args.estimator):
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
