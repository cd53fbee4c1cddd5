"""The mapped pipe that reaches into a fitting's gap (issue 22, stop 43): per mapped pipe, the true pipes
it lies on, and the centimetres of it beyond 5 cm of truth that lie past a true pipe's end where a
fitting is (a ground-truth object within 0.3 m of that end; ``beyond_5cm.py``'s "past_fitting_end",
navigation not taken out), by fitting: whether a mapped object is there (the map's pipe ends stop at the
mapped fittings' port mouths), and the line observations of each true pipe ending there that reach past
its end by more than 2 cm, placed with the true poses (the front-end's segment ends) and with the
graph's final poses. Replays the laser observations that
``experiments/laser_real_eval.py pipeline --dump DIR`` recorded (as ``pipeline_replay.py``).

    python experiments/laser/fitting_gap_trace.py --seeds 15,23,19 --dump DIR
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent), str(HERE.parent / "estimators")]

from beyond_5cm import _nearest  # noqa: E402
from laser_real_eval import PIPE_GATE_M, parse_seeds  # noqa: E402
from pipeline_replay import replay, true_poses  # noqa: E402

FITTING_M = 0.3


def _graph_poses(graph):
    """A function of a stamp: the graph's final body pose T_WB then (4×4, interpolated)."""
    interp = graph.trajectory.interpolator()

    def at(stamp: int) -> np.ndarray:
        R, t = interp(np.array([stamp]))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[0], t[0]
        return T

    return at


def trace(seed: int, dump: Path) -> list[str]:
    from frontends.laser.evaluation import matching_pipe
    from semslam.observations import LineObservation

    results, mission, by_stamp = replay(seed, dump, {}, {})
    graph = results["graph"]
    gt = mission.metadata.ground_truth
    objects = np.array([o.position for o in gt.objects], float).reshape(-1, 3)
    mapped_objects = np.array([lm.position for lm in graph.landmarks if lm.kind == "object"]).reshape(-1, 3)
    pose_at = true_poses(mission)
    graph_at = _graph_poses(graph)
    T_BS = next(s for s in mission.metadata.sensors.values() if s.kind == "laser").T_BS
    # every line observation placed with the true pose and the graph's, with its true pipe
    placed = []
    for stamp in sorted(by_stamp):
        T = pose_at(stamp)[1]
        Tg = graph_at(stamp)
        for z in by_stamp[stamp]:
            if not isinstance(z, LineObservation):
                continue
            P = np.stack([z.p, z.q]) @ T[:3, :3].T + T[:3, 3]
            k = matching_pipe(P[0], P[1], gt.pipes)
            if k is None:
                continue
            TgS = Tg @ T_BS
            G = np.stack([z.p, z.q]) @ TgS[:3, :3].T + TgS[:3, 3]
            placed.append((stamp, k, P, G))
    out = []
    for lm in (lm for lm in graph.landmarks if lm.kind == "pipe" and lm.p is not None):
        L = max(float(np.linalg.norm(lm.q - lm.p)), 0.01)
        x = lm.p + np.outer(np.arange(0, 1.0001, 0.01 / L), lm.q - lm.p)
        d, which, t, GL = _nearest(x, gt.pipes)
        spans = sorted({gt.pipes[k].id for k in which})
        past = (d > PIPE_GATE_M) & ((t < 0.0) | (t > GL))
        by_fitting: dict[int, list[int]] = {}
        for i in np.flatnonzero(past):
            g = gt.pipes[which[i]]
            end = np.asarray(g.p if t[i] < 0.0 else g.q, float)
            j = int(np.argmin(np.linalg.norm(objects - end, axis=1))) if len(objects) else -1
            if j >= 0 and np.linalg.norm(objects[j] - end) <= FITTING_M:
                by_fitting.setdefault(j, []).append(i)
        for j, idx in by_fitting.items():
            o = gt.objects[j]
            mapped = float(np.linalg.norm(mapped_objects - objects[j], axis=1).min()) if len(mapped_objects) else None
            # the true pipes ending at this fitting, and the views of each that reach past that end
            ends_here = []
            for g in gt.pipes:
                gp, gq = np.asarray(g.p, float), np.asarray(g.q, float)
                Lg = float(np.linalg.norm(gq - gp))
                a = (gq - gp) / Lg
                for e, e_s, sign in ((gp, 0.0, -1.0), (gq, Lg, 1.0)):
                    if np.linalg.norm(e - objects[j]) <= FITTING_M:
                        over = [
                            (float(np.max(sign * ((P - gp) @ a - e_s))), float(np.max(sign * ((G - gp) @ a - e_s))), st)
                            for st, kk, P, G in placed
                            if kk.id == g.id
                        ]
                        ends_here.append((g.id, over))
            views = "; ".join(
                f"pipe {gid}: {len(ov)} views, past by > 2 cm {sum(o_t > 0.02 for o_t, _, _ in ov)} with the true poses "
                f"(max {100 * max((o_t for o_t, _, _ in ov), default=0.0):.1f} cm), "
                f"{sum(o_g > 0.02 for _, o_g, _ in ov)} with the graph's"
                for gid, ov in ends_here
            )
            out.append(
                f"  mapped pipe {lm.id} (on true pipes {spans}): {len(idx)} cm beyond 5 cm past a pipe end at "
                f"{o.cls} {o.id} ({'mapped, ' + f'{100 * mapped:.1f} cm off' if mapped is not None and mapped < 0.2 else 'not mapped'}); "
                f"{views}"
            )
    return [f"seed {seed}:", *out]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--dump", required=True, help="directory (may hold {seed})")
    args = ap.parse_args()
    for seed in parse_seeds(args.seeds):
        print("\n".join(trace(seed, Path(args.dump.format(seed=seed)))), flush=True)


if __name__ == "__main__":
    main()
