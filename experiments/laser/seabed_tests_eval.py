"""The seabed tests of the pipe stage, per segment, against the truth (issue 22): what each test
measures on segments that lie on true pipes and on those that do not (stones, crests, mounds).

    python experiments/laser/seabed_tests_eval.py collect --seeds 4,9 --every 3 --out /tmp/seabed.json
    python experiments/laser/seabed_tests_eval.py report /tmp/seabed.json [--set pipes.key=value ...]

``collect`` simulates each pipeline seed and segments every ``--every``-th cloud with this checkout's
front-end ("up" from the true pose); every segment that reaches the seabed tests
(``Seabed.accept``: found lying on the ground or over unknown ground) is recorded with what the tests
read (axis height, arc, bow and its standard error, colour contrast, plus the colour distance split
into brightness and chromaticity), its length and radius, and its label: on a true pipe
(``matching_pipe``: 10°, 5 cm) or not. ``report`` prints, for true and false segments, percentiles
of each reading, and how many of each kind the current rule (or the rule with ``--set`` changes)
accepts.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from laser_real_eval import parse_seeds  # noqa: E402


def collect(seeds: list[int], every: int, out: Path) -> None:
    import frontends.laser.pipe_shape as pipe_shape
    from frontends.laser.config import LaserConfig
    from frontends.laser.evaluation import matching_pipe
    from frontends.laser.frontend import segment_scan
    from frontends.laser.pipe_shape import arc_span_deg, axis_height, bow
    from semslam.mission.measurements import GroundTruthPose, PointCloud
    from semslam.sim.pipeline_config import PipelineSimConfig
    from semslam.sim.pipeline_mission import simulate_pipeline

    cfg = LaserConfig()
    seen: list = []
    accept = pipe_shape.Seabed.accept

    def recording_accept(self, pipe, seen_length=0.0):
        ok = accept(self, pipe, seen_length)
        row = {"ok": bool(ok), "length": pipe.length, "radius": pipe.radius}
        row["axis_h"] = axis_height(pipe, self.ground)
        row["arc"] = arc_span_deg(pipe, self.points)
        row["bow"], row["bow_se"] = bow(pipe, self.points)
        row["range"] = float(np.linalg.norm(0.5 * (pipe.p + pipe.q)))
        row.update(colour_parts(self, pipe))
        seen.append((pipe, row))
        return ok

    pipe_shape.Seabed.accept = recording_accept
    rows = []
    for seed in seeds:
        mission = simulate_pipeline(PipelineSimConfig(seed=seed))
        meta = mission.metadata
        gt = meta.ground_truth
        T_BS = next(s for s in meta.sensors.values() if s.kind == "laser").T_BS
        poses = {m.stamp: m.matrix() for m in mission.of_type(GroundTruthPose)}
        stamps = np.array(sorted(poses))
        for k, m in enumerate(mission.of_type(PointCloud)):
            if k % every:
                continue
            T = poses[int(stamps[np.argmin(np.abs(stamps - m.stamp))])] @ T_BS
            R, t = T[:3, :3], T[:3, 3]
            seen.clear()
            segment_scan(m.points, cfg, up=R.T @ np.array([0.0, 0.0, -1.0]), rgb=m.rgb)
            for pipe, row in seen:
                P = np.stack([pipe.p, pipe.q]) @ R.T + t
                g = matching_pipe(P[0], P[1], gt.pipes)
                row.update(seed=seed, stamp=int(m.stamp), true=g is not None, pipe=None if g is None else int(g.id))
                row["true_radius"] = None if g is None else float(g.radius)
                rows.append(row)
        print(f"seed {seed}: {sum(r['seed'] == seed for r in rows)} segments tested", flush=True)
        out.write_text(json.dumps(rows))


def colour_parts(seabed, pipe) -> dict:
    """The colour contrast of ``pipe`` with the ground around it (as the test reads it), and its
    split: the difference of brightness (mean of the channels) and of chromaticity (each colour
    divided by its brightness, × the ground's brightness: 0-255 scale)."""
    from frontends.laser.grid import row_dot

    if seabed._rgb is None:
        return {}
    contrast = seabed._contrast(pipe)  # fills the raw ground mask too
    own = seabed._raw_index(pipe.inliers)
    raw, rgb = seabed._raw, np.asarray(seabed._rgb, float)
    P = raw - pipe.p
    t = P @ pipe.axis
    reach = seabed.cfg.color_reach
    near = (t > -reach) & (t < pipe.length + reach)
    near &= row_dot(P, P) - t * t <= (pipe.radius + reach) ** 2
    ground = np.flatnonzero(near & seabed._raw_ground)
    if contrast is None or len(own) < 10 or len(ground) < 10:
        return {"contrast": contrast}
    a, b = np.median(rgb[own], axis=0), np.median(rgb[ground], axis=0)
    ba, bb = a.mean(), b.mean()
    return {
        "contrast": contrast,
        "brightness": float(ba - bb),
        "chroma": float(np.linalg.norm(a / max(ba, 1e-9) - b / max(bb, 1e-9)) * bb),
        "own_rgb": a.round(1).tolist(),
        "ground_rgb": b.round(1).tolist(),
    }


def report(path: Path, sets: list[str]) -> None:
    from frontends.laser.config import PipeConfig

    rows = json.loads(path.read_text())
    upd = {}
    for item in sets:
        key, value = item.split("=", 1)
        upd[key.split(".")[-1]] = float(value)
    cfg = PipeConfig(**upd)
    keys = ("length", "axis_h", "arc", "bow", "contrast", "brightness", "chroma")
    for label in (True, False):
        sel = [r for r in rows if r["true"] is label]
        print(f"{'true' if label else 'false'} segments: {len(sel)} (accepted now: {sum(r['ok'] for r in sel)})")
        for key in keys:
            v = np.array([r[key] for r in sel if r.get(key) is not None], float)
            if len(v):
                print(f"  {key:10s} " + " ".join(f"p{q}={np.percentile(v, q):.4g}" for q in (5, 25, 50, 75, 95)))
    print("per seed (true / false accepted now, reported length):")
    for seed in sorted({r["seed"] for r in rows}):
        sel = [r for r in rows if r["seed"] == seed and r["length"] >= cfg.min_partial_length]
        print(
            f"  seed {seed}: true {sum(r['ok'] and r['true'] for r in sel)}/{sum(r['true'] for r in sel)}, "
            f"false {sum(r['ok'] and not r['true'] for r in sel)}/{sum(not r['true'] for r in sel)}"
        )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("--seeds", default="4,9")
    c.add_argument("--every", type=int, default=3)
    c.add_argument("--out", type=Path, required=True)
    r = sub.add_parser("report")
    r.add_argument("path", type=Path)
    r.add_argument("--set", action="append", default=[])
    args = ap.parse_args(argv)
    if args.cmd == "collect":
        collect(parse_seeds(args.seeds), args.every, args.out)
    else:
        report(args.path, args.set)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
