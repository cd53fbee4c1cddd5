"""Where each estimator's map sits against the truth, and against its own trajectory (issue 21, stop 45).

Reads the dumps of ``replay_study.py run --dump DIR`` and the recorded laser observations and prints,
per world and estimator (horizontal vectors, cm, x/y):

- ``map``: the map's rigid offset, the least-squares translation of the matched landmarks onto the truth
  (an object gives both axes, a pipe only the component across its axis), and the RMS of what is left;
- ``traj``: the trajectory's mean error from the first laser landmark view on, and ``first`` its error
  at that view;
- ``own``: the offset of the map that the estimator's own trajectory would make, every object and pipe
  view placed by its pose at the view's stamp (views told apart by the truth: the true pose places
  them, the nearest true landmark within 0.15 m takes them), the same least-squares translation; ``fe``
  the same with the true poses (the front-end's own offset, what no estimator can remove);
- ``map−own``: how far the map is from where its own trajectory puts the landmarks; near zero the map is
  rigidly consistent with its trajectory.

Then the landmark median errors (all matched landmarks, as metrics.json's ``landmark_median_error_m``)
unaligned and after removing the map's own offset.

    python experiments/estimators/replay_study.py run --cache DIR --seeds 3,60 --estimators graph,ekf --dump D
    python experiments/estimators/map_offset.py D --cache DIR --seeds 3,60
"""

from __future__ import annotations

import argparse
import json
import pickle
from collections import Counter
from pathlib import Path

import numpy as np

from semslam.eval.metrics import match_landmarks
from semslam.mission.ground_truth import GroundTruthMap
from semslam.study.plan import parse_seeds

ESTIMATORS = ("graph", "ekf")
VIEW_GATE_M = 0.15


def _rows(items) -> tuple[np.ndarray, np.ndarray]:
    """Stack (error vector 2, None) for an object or (error 2, unit normal 2) for a pipe into the
    least-squares rows A t = b of the horizontal translation t."""
    A, b = [], []
    for e, n in items:
        if n is None:
            A += [[1.0, 0.0], [0.0, 1.0]]
            b += [e[0], e[1]]
        else:
            A.append(n)
            b.append(float(n @ e))
    return np.array(A, float).reshape(-1, 2), np.array(b, float)


def offset(items) -> tuple[np.ndarray, float]:
    """(least-squares horizontal translation of the errors, RMS of the rows left after it)."""
    A, b = _rows(items)
    if len(b) < 2:
        return np.full(2, np.nan), np.nan
    t = np.linalg.lstsq(A, b, rcond=None)[0]
    return t, float(np.sqrt(np.mean((b - A @ t) ** 2)))


def _pipe_item(a: np.ndarray, c: np.ndarray, g) -> tuple[np.ndarray, np.ndarray]:
    """A segment a–c against true pipe g: the horizontal error of its midpoint across the axis, and the
    axis's horizontal normal (a vertical pipe's error is left out by the caller)."""
    p, q = np.array(g.p), np.array(g.q)
    d = (q - p)[:2] / np.linalg.norm((q - p)[:2])
    n = np.array([-d[1], d[0]])
    m = 0.5 * (a + c)[:2] - p[:2]
    return n * float(n @ m), n


def _vertical(g) -> bool:
    """A pipe more vertical than not leaves no horizontal normal to measure an offset along."""
    d = np.subtract(g.q, g.p)
    return bool(np.linalg.norm(d[:2]) < 0.3 * np.linalg.norm(d))


def map_items(landmarks, truth: GroundTruthMap) -> list:
    matches, _ = match_landmarks(landmarks, truth)
    by_id = {lm.id: lm for lm in landmarks}
    objs = {g.id: g for g in truth.objects}
    pipes = {g.id: g for g in truth.pipes}
    items = []
    for m in matches:
        lm = by_id[m.estimate_id]
        if m.kind == "object":
            items.append(((lm.position - np.array(objs[m.truth_id].position))[:2], None))
        elif m.kind == "pipe" and not _vertical(pipes[m.truth_id]):
            items.append(_pipe_item(lm.p, lm.q, pipes[m.truth_id]))
    return items, matches


def views(obs: dict, truth_traj, T_BS: np.ndarray, truth: GroundTruthMap) -> list:
    """(stamp, kind, points in the body frame (k×3), true landmark) of every laser object/pipe view that
    the true pose places within VIEW_GATE_M of a true landmark."""
    items = [(s, x) for s, v in obs.items() for x in v if type(x).__name__ in ("PointObservation", "LineObservation")]
    if not items:
        return []
    stamps = np.array([s for s, _ in items], np.int64)
    R, p = truth_traj.poses_at(stamps)
    out = []
    obj_at = np.array([g.position for g in truth.objects], float).reshape(-1, 3)
    for (s, x), Rk, pk in zip(items, R, p):
        pts = np.array([x.position] if hasattr(x, "position") else [x.p, x.q], float)
        body = pts @ T_BS[:3, :3].T + T_BS[:3, 3]
        world = body @ Rk.T + pk
        if len(pts) == 1:
            if not len(obj_at):
                continue
            d = np.linalg.norm(obj_at - world[0], axis=1)
            j = int(np.argmin(d))
            if d[j] <= VIEW_GATE_M:
                out.append((s, "object", body, truth.objects[j]))
        else:
            best = None
            for g in truth.pipes:
                if _vertical(g):
                    continue
                a, b = np.array(g.p), np.array(g.q)
                u = (b - a) / np.linalg.norm(b - a)
                v = world - a
                c = float(np.mean(np.linalg.norm(v - np.outer(v @ u, u), axis=1)))
                if best is None or c < best[0]:
                    best = (c, g)
            if best is not None and best[0] <= VIEW_GATE_M:
                out.append((s, "pipe", body, best[1]))
    return out


def placed_items(vs: list, traj) -> list:
    """The views placed by ``traj``'s poses at their stamps, as offset() items."""
    if not vs:
        return []
    R, p = traj.poses_at(np.array([s for s, *_ in vs], np.int64))
    items = []
    for (_, kind, body, g), Rk, pk in zip(vs, R, p):
        world = body @ Rk.T + pk
        if kind == "object":
            items.append(((world[0] - np.array(g.position))[:2], None))
        else:
            items.append(_pipe_item(world[0], world[1], g))
    return items


def shifted_median(landmarks, truth: GroundTruthMap, t: np.ndarray) -> float:
    """The landmark median error with the map moved by −t (horizontal)."""
    T = np.array([t[0], t[1], 0.0])
    moved = []
    for lm in landmarks:
        m = object.__new__(type(lm))
        m.__dict__.update(lm.__dict__)
        for f in ("position", "p", "q"):
            if getattr(lm, f) is not None:
                m.__dict__[f] = getattr(lm, f) - T
        moved.append(m)
    matches, _ = match_landmarks(moved, truth)
    return float(np.median([m.error_m for m in matches])) if matches else np.nan


def world(dump: Path, cache: Path) -> dict:
    keep, truth_traj = pickle.loads(dump.read_bytes())
    stem = dump.name.removesuffix(".result.pkl")
    side = json.loads((cache / f"{stem}.bag.semslam.json").read_text())
    truth = GroundTruthMap.from_dict(side["ground_truth"])
    T_BS = np.array(side["sensors"]["laser"]["T_BS"], float)
    obs = pickle.loads((cache / f"{stem}.obs.pkl").read_bytes())["observations"].get("laser", {})
    vs = views(obs, truth_traj, T_BS, truth)
    t1 = min(s for s, *_ in vs)
    per_scan = np.array(sorted(Counter(s for s, *_ in vs).items()))
    t_dense = int(per_scan[np.argmax(per_scan[:, 1] >= 0.5 * np.median(per_scan[:, 1])), 0])
    out = {"first_view_s": (t1 - truth_traj.stamps[0]) * 1e-9, "dense_s": (t_dense - truth_traj.stamps[0]) * 1e-9}
    out["views"] = len(vs)
    out["fe"] = offset(placed_items(vs, truth_traj))
    for est in ESTIMATORS:
        traj, landmarks = keep[est]
        items, matches = map_items(landmarks, truth)
        t_map, rest = offset(items)
        _, p_true = truth_traj.poses_at(traj.stamps)
        e = (traj.positions - p_true)[:, :2]
        after = traj.stamps >= t1
        k = int(np.argmax(after))
        kd = int(np.argmax(traj.stamps >= t_dense))
        sig = [np.sqrt(np.diag(lm.covariance)[:2].mean()) for lm in landmarks if lm.kind == "object"]
        own, own_rest = offset(placed_items(vs, traj))
        out[est] = {
            "map": t_map,
            "map_rest": rest,
            "traj": e[after].mean(0),
            "first": e[k],
            "dense": e[kd],
            "sigma": float(np.median(sig)) if sig else np.nan,
            "own": own,
            "own_rest": own_rest,
            "median": float(np.median([m.error_m for m in matches])),
            "median_shifted": shifted_median(landmarks, truth, t_map),
        }
    return out


def _v(x: np.ndarray) -> str:
    return f"{x[0] * 100:+5.2f},{x[1] * 100:+5.2f}"


def summary(rows: dict) -> None:
    """What the worlds share: where each map's offset comes from, and the graph-vs-EKF counts."""
    n = len(rows)
    norm = lambda est, a, b: np.array([np.linalg.norm(r[est][a] - (r[est][b] if b else 0)) for r in rows.values()])  # noqa: E731
    for est in ESTIMATORS:
        print(
            f"{est}: |map| median {np.median(norm(est, 'map', None)) * 100:.2f} cm; |map − first-view error| "
            f"{np.median(norm(est, 'map', 'first')) * 100:.2f}; |map − dense-view error| "
            f"{np.median(norm(est, 'map', 'dense')) * 100:.2f}; |map − own placement| "
            f"{np.median(norm(est, 'map', 'own')) * 100:.2f}; |map|/σ_obj median "
            f"{np.median(norm(est, 'map', None) / [r[est]['sigma'] for r in rows.values()]):.2f}"
        )
    g, e = norm("graph", "map", None), norm("ekf", "map", None)
    G = np.array([r["graph"]["map"] for r in rows.values()])
    E = np.array([r["ekf"]["map"] for r in rows.values()])
    corr = [float(np.corrcoef(G[:, k], E[:, k])[0, 1]) for k in (0, 1)]
    print(
        f"|map| graph ≤ EKF on {int((g <= e).sum())}/{n}; graph−EKF offset |Δ| median "
        f"{np.median(np.linalg.norm(G - E, axis=1)) * 100:.2f} cm; x/y correlation {corr[0]:.2f}/{corr[1]:.2f}"
    )
    for key in ("median", "median_shifted"):
        worse = [k.split("seed")[1] for k, r in rows.items() if r["graph"][key] > r["ekf"][key]]
        print(f"landmark {key}: graph ≤ EKF on {n - len(worse)}/{n}; worse on {','.join(worse)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dump", type=Path, help="the --dump directory of replay_study.py run")
    ap.add_argument("--cache", type=Path, required=True, help="the bags' sidecars and recorded observations")
    ap.add_argument("--seeds", type=parse_seeds, help="these worlds only (default: every dump)")
    ap.add_argument("--json", type=Path, help="write the per-world figures here")
    args = ap.parse_args()
    files = sorted(args.dump.glob("*.result.pkl"), key=lambda f: int(f.name.split("seed")[1].split(".")[0]))
    if args.seeds:
        files = [f for f in files if int(f.name.split("seed")[1].split(".")[0]) in set(args.seeds)]
    print(
        "world first,dense(s) fe | est: median/shifted(mm) map[rest] traj first dense own[rest] |map-own| "
        "|map-traj| (cm) σ_obj (cm)"
    )
    rows = {}
    for f in files:
        r = world(f, args.cache)
        rows[f.name.removesuffix(".result.pkl")] = r
        parts = [f"{f.name.split('.')[0]:12s} {r['first_view_s']:4.1f},{r['dense_s']:4.1f} fe {_v(r['fe'][0])}"]
        for est in ESTIMATORS:
            x = r[est]
            parts.append(
                f"{est}: {x['median'] * 1e3:5.1f}/{x['median_shifted'] * 1e3:4.1f} map {_v(x['map'])}"
                f"[{x['map_rest'] * 100:.2f}] traj {_v(x['traj'])} first {_v(x['first'])} dense {_v(x['dense'])} "
                f"own {_v(x['own'])}"
                f"[{x['own_rest'] * 100:.2f}] {np.linalg.norm(x['map'] - x['own']) * 100:.2f} "
                f"{np.linalg.norm(x['map'] - x['traj']) * 100:.2f} σ {x['sigma'] * 100:.1f}"
            )
        print(" | ".join(parts), flush=True)
    summary(rows)
    if args.json:
        conv = lambda o: o.tolist() if isinstance(o, np.ndarray) else float(o)  # noqa: E731
        args.json.write_text(json.dumps(rows, indent=1, default=conv))


if __name__ == "__main__":
    main()
