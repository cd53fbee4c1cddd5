"""Benchmark of the laser front-end: median time per ~100k-point scan, per stage.

Scans are those of the simulated tank mission (``--source tank``, every ``--every``-th, the known
pipe radius as prior, "up" from the true pose as the AHRS gives it), the stereo clouds of the
simulated pipeline (``--source pipeline``: organised 240×180 clouds, ~40k valid points, with RGB and
"up"; issue 22's target: ≤ 0.2 s median per cloud) or ray-cast views of the synthetic mock-up
(``--source synthetic``, no "up"), each processed ``--repeat`` times; reports the median wall time and the median CPU time of the process (on a
machine shared with other jobs the wall time includes waiting for a core; CPU time does not, but
counts both cores when a library runs two threads). Target (issue 6): ≤ 0.2 s per 100k-point scan.
With ``--process``, also ``LaserFrontend.process`` (the geometry and the recognition of every object
of the scan, what a mission pays per scan; issue 9 aims at ≤ 0.12 s).

With ``--against DIR`` (another checkout of the repository, e.g. a ``git worktree`` of the commit
before a change), a paired comparison instead: one worker process per checkout, the two taking the
same scans alternately (so a change of the machine's load falls on both), each result hashed (pipes,
their inliers and covariances, objects, plane mask) to check that the outputs are identical; reports
both medians and the median of the per-scan ratios. On the loaded 2-core machine, an A/A run of the
same checkout gives a ratio within ~2 % of 1. With ``--process`` too, the workers time
``LaserFrontend.process`` instead (recognition included) and the hash also covers its observations
(clouds, class likelihoods, connectivity).

    python experiments/bench_laser.py [--source tank] [--scans 8] [--repeat 3] [--process] [--config '{...}']
    python experiments/bench_laser.py --source pipeline --every 5 --scans 40 --repeat 1
    python experiments/bench_laser.py --source pipeline --against /tmp/before --every 5 --scans 40 --repeat 1
    python experiments/bench_laser.py --against /tmp/before --every 3 --scans 82 --repeat 1
    python experiments/bench_laser.py --against /tmp/before --every 3 --scans 40 --repeat 1 --process
    python experiments/bench_laser.py --against /tmp/before --scans-file /tmp/tank.npz --config-b '{"pipes": {...}}'
    python experiments/bench_laser.py --scans-file /tmp/tank.npz --profile 40   # cProfile (CPU time), top 40 functions

Reports medians and 95th percentiles of the per-scan times (paired: of both checkouts).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

# (a paired comparison's worker imports the front-end of the checkout it is given)
sys.path.insert(0, os.environ.get("BENCH_LASER_ROOT") or str(Path(__file__).resolve().parents[1]))

from frontends.laser import LaserConfig, segment_scan  # noqa: E402
from semslam.sim.vary import merge_into  # noqa: E402
from tests.support.synthetic import default_scene, raycast, viewpoint  # noqa: E402


def _segment(scan: dict, cfg):
    """``segment_scan`` of a scan ({"points", "up", "rgb"}), given what this checkout's accepts (an
    older one may take no ``rgb``)."""
    import inspect

    accepted = inspect.signature(segment_scan).parameters
    kwargs = {k: scan[k] for k in ("up", "rgb") if k in accepted and scan.get(k) is not None}
    return segment_scan(scan["points"], cfg, **kwargs)


def _save(path: Path, scans: list[dict]) -> None:
    arrays = {}
    for k, sc in enumerate(scans):
        arrays[f"p{k}"] = sc["points"]
        for key, name in (("up", "u"), ("rgb", "c")):
            if sc.get(key) is not None:
                arrays[f"{name}{k}"] = sc[key]
    np.savez(path, **arrays)


def _load(path: Path) -> list[dict]:
    data = np.load(path)
    n = sum(1 for key in data.files if key.startswith("p"))
    return [{"points": data[f"p{k}"], "up": data.get(f"u{k}"), "rgb": data.get(f"c{k}")} for k in range(n)]


def _bench_process(scans, overrides: dict, repeat: int) -> dict:
    """Median wall and CPU time of ``LaserFrontend.process`` per scan, and of its recognition."""
    from frontends.laser import LaserFrontend
    from semslam.mission.measurements import PointCloud

    fe = LaserFrontend(None, overrides)
    clouds = [PointCloud(stamp=k, sensor="laser", points=sc["points"], rgb=sc.get("rgb")) for k, sc in enumerate(scans)]
    fe.process(clouds[0])  # warm-up: builds (or loads) the recogniser's view database
    wall, cpu, n_objects = [], [], []
    for pc in clouds:
        for _ in range(repeat):
            c0, w0 = time.process_time(), time.perf_counter()
            obs = fe.process(pc)
            wall.append(time.perf_counter() - w0)
            cpu.append(time.process_time() - c0)
        n_objects.append(sum(1 for o in obs if getattr(o, "class_likelihood", None) is not None))
    return {
        "wall_median_s": round(float(np.median(wall)), 4),
        "cpu_median_s": round(float(np.median(cpu)), 4),
        "recognised_objects_per_scan": float(np.median(n_objects)),
    }


def _hash_segmentation(h, seg) -> None:
    """Adds a segmentation's outputs (plane mask, pipes with inliers and covariances, objects) to ``h``."""
    h.update(seg.planes.structure.tobytes())
    for p in seg.pipes:
        h.update(np.concatenate([p.p, p.q, p.covariance.ravel()]).tobytes() + p.inliers.tobytes())
    for o in seg.objects:
        h.update(o.position.tobytes() + o.covariance.tobytes() + o.indices.tobytes() + bytes([o.configuration]))


def _hash_observations(h, obs) -> None:
    """Adds ``LaserFrontend.process``'s observations (with clouds and class likelihoods) to ``h``."""
    for o in obs:
        for name in ("p", "q", "covariance", "position", "cloud"):
            v = getattr(o, name, None)
            if v is not None:
                h.update(name.encode() + np.ascontiguousarray(v).tobytes())
        lik = getattr(o, "class_likelihood", None)
        h.update(repr(sorted(lik.items()) if lik is not None else None).encode())
        h.update(repr(getattr(o, "connectivity", None)).encode())


def _worker(path: Path, overrides: dict, process: bool = False) -> int:
    """Worker of the paired comparison: reads scan indices on stdin, answers (cpu, wall, stage CPU
    times, hash of the result) pickled and length-prefixed on stdout. With ``process``, times
    ``LaserFrontend.process`` (recognition included) and hashes its observations too."""
    import hashlib
    import pickle

    scans = _load(path)
    cfg = LaserConfig.model_validate(overrides)
    if process:
        from frontends.laser import LaserFrontend
        from semslam.mission.measurements import PointCloud

        fe = LaserFrontend(None, overrides)
        fe.recognizer  # warm-up: builds (or loads) the recogniser's view database  # noqa: B018
        fe.process(PointCloud(stamp=0, sensor="laser", points=scans[0]["points"]))
    else:
        _segment(scans[0], cfg)  # warm-up
    out = sys.stdout.buffer
    for line in sys.stdin:
        scan = scans[int(line)]
        h = hashlib.sha1()
        c0, w0 = time.process_time(), time.perf_counter()
        if process:
            obs = fe.process(PointCloud(stamp=int(line), sensor="laser", points=scan["points"]))
            seg = fe.last
        else:
            seg = _segment(scan, cfg)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        _hash_segmentation(h, seg)
        if process:
            _hash_observations(h, obs)
        stages = {k[4:]: v for k, v in seg.timings.items() if k.startswith("cpu_")}
        msg = pickle.dumps((cpu, wall, stages, h.hexdigest()))
        out.write(len(msg).to_bytes(8, "little") + msg)
        out.flush()
    return 0


def _paired(
    scans: list, overrides: dict, against: Path, repeat: int, process: bool = False, overrides_b: dict | None = None
) -> dict:
    """Paired A/B: this checkout (B) and ``against`` (A) in two workers, taking the scans alternately
    (with ``process``: ``LaserFrontend.process``, recognition included); ``overrides_b``: merged over
    ``overrides`` for B only (a setting A's checkout may not know)."""
    import pickle
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scans.npz"
        _save(path, scans)
        here = Path(__file__).resolve().parents[1]
        workers = {}
        for name, root in (("A", Path(against).resolve()), ("B", here)):
            cmd = [
                sys.executable,
                str(Path(__file__).resolve()),
                "--worker",
                str(path),
                "--config",
                json.dumps(overrides if name == "A" else merge_into(copy.deepcopy(overrides), overrides_b or {})),
            ]
            cmd += ["--process"] if process else []
            env = dict(os.environ, BENCH_LASER_ROOT=str(root))
            workers[name] = subprocess.Popen(cmd, cwd=root, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE)

        def ask(name: str, k: int):
            w = workers[name]
            w.stdin.write(f"{k}\n".encode())
            w.stdin.flush()
            n = int.from_bytes(w.stdout.read(8), "little")
            return pickle.loads(w.stdout.read(n))

        res: dict[str, list] = {"A": [], "B": []}
        identical = True
        for k in range(len(scans) * repeat):
            i = k % len(scans)
            got = {name: ask(name, i) for name in (("A", "B") if k % 2 == 0 else ("B", "A"))}
            for name in got:
                res[name].append(got[name])
            identical &= got["A"][3] == got["B"][3]
        for w in workers.values():
            w.stdin.close()
            w.wait()

    def med(name, j, q=50):
        return round(float(np.percentile([r[j] for r in res[name]], q)), 4)

    ratio = {j: round(float(np.median([b[j] / a[j] for a, b in zip(res["A"], res["B"])])), 3) for j in (0, 1)}
    stages = sorted(res["A"][0][2])
    return {
        "against": str(against),
        "timed": "LaserFrontend.process" if process else "segment_scan",
        "runs": len(res["A"]),
        "identical_results": bool(identical),
        "cpu_median_s": {"A": med("A", 0), "B": med("B", 0), "median_ratio_B_A": ratio[0]},
        "cpu_p95_s": {"A": med("A", 0, 95), "B": med("B", 0, 95)},
        "wall_median_s": {"A": med("A", 1), "B": med("B", 1), "median_ratio_B_A": ratio[1]},
        "wall_p95_s": {"A": med("A", 1, 95), "B": med("B", 1, 95)},
        "stage_cpu_median_s": {
            st: {n: round(float(np.median([r[2][st] for r in res[n]])), 4) for n in ("A", "B")} for st in stages
        },
        "load_average_1min": round(os.getloadavg()[0], 2),
    }


def _mission_scans(source: str, seed: int, every: int, n: int, overrides: dict) -> list[dict]:
    """Every ``every``-th cloud of the simulated tank or pipeline mission (at most ``n``), with "up"
    from the true pose at its stamp (as the AHRS gives it) and the cloud's colours. For the tank,
    its pipes' known radius becomes the prior (as in ``semslam demo``)."""
    from semslam.mission.measurements import GroundTruthPose, PointCloud

    if source == "tank":
        from semslam.sim import TankSimConfig, simulate_tank

        sim = TankSimConfig(seed=seed)
        overrides.setdefault("pipes", {}).setdefault("radius_prior", sim.structure.pipe_radius_m)
        mission = simulate_tank(sim)
    else:
        from semslam.sim.pipeline_config import PipelineSimConfig
        from semslam.sim.pipeline_mission import simulate_pipeline

        mission = simulate_pipeline(PipelineSimConfig(seed=seed))
    sensor = next(s for s in mission.metadata.sensors.values() if s.kind == "laser")
    poses = {m.stamp: m for m in mission.of_type(GroundTruthPose)}
    stamps = np.array(sorted(poses))
    out = []
    for c in list(mission.of_type(PointCloud))[every // 2 :: every][:n]:
        T_WS = poses[int(stamps[np.argmin(np.abs(stamps - c.stamp))])].matrix() @ sensor.T_BS
        out.append({"points": c.points, "up": T_WS[:3, :3].T @ np.array([0.0, 0.0, -1.0]), "rgb": c.rgb})
    return out


def _profile(scans: list[dict], cfg, top: int) -> int:
    """cProfile of ``segment_scan`` over the scans: the top functions by own time and by cumulative
    time (per scan: divide by the number of scans), in CPU time of the process: with the default
    wall clock, on a shared machine the waits for a core are charged to whichever call was running
    (a system call such as ``time.process_time`` showed milliseconds a call). The timer's own cost
    (~1 µs a call) inflates the totals, not the shares of the larger functions."""
    import cProfile
    import pstats

    prof = cProfile.Profile(time.process_time)
    prof.enable()
    for scan in scans:
        _segment(scan, cfg)
    prof.disable()
    print(f"{len(scans)} scans")
    for key in ("tottime", "cumulative"):
        pstats.Stats(prof).strip_dirs().sort_stats(key).print_stats(top)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--config", type=str, default="{}")
    ap.add_argument(
        "--config-b", type=str, default="{}", help="with --against: overrides for this checkout (B) only, over --config"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--source", choices=("tank", "pipeline", "synthetic"), default="tank")
    ap.add_argument("--every", type=int, default=25, help="tank, pipeline: every n-th scan")
    ap.add_argument("--process", action="store_true", help="also time LaserFrontend.process (with recognition)")
    ap.add_argument("--profile", type=int, default=0, help="print cProfile's top N functions of segment_scan")
    ap.add_argument("--against", type=Path, default=None, help="paired A/B against this checkout (see above)")
    ap.add_argument(
        "--scans-file", type=Path, default=None, help="the scans are read from this .npz if it exists, else saved to it"
    )
    ap.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)  # internal: scans file
    args = ap.parse_args(argv)
    if args.worker is not None:
        return _worker(args.worker, json.loads(args.config), args.process)
    overrides = json.loads(args.config)
    scans = []
    if args.scans_file is not None and args.scans_file.exists():
        scans = _load(args.scans_file)
        if args.source == "tank":  # (the prior _mission_scans sets, from the default tank's radius)
            from semslam.sim import TankSimConfig

            overrides.setdefault("pipes", {}).setdefault(
                "radius_prior", TankSimConfig(seed=args.seed).structure.pipe_radius_m
            )
    elif args.source in ("tank", "pipeline"):
        scans = _mission_scans(args.source, args.seed, args.every, args.scans, overrides)
    else:
        rng = np.random.default_rng(args.seed)
        for i in range(args.scans):
            T = viewpoint(rng.uniform(0, 360), rng.uniform(-0.3, 0.3, 2), rng.uniform(-10, 10), rng.uniform(-0.5, 0.3))
            scans.append({"points": raycast(default_scene(), n_rays=args.rays, T_scene=T, seed=i).points})
    if args.scans_file is not None and not args.scans_file.exists():
        _save(args.scans_file, scans)
    if args.against is not None:
        print(
            json.dumps(
                _paired(scans, overrides, args.against, args.repeat, args.process, json.loads(args.config_b)), indent=2
            )
        )
        return 0
    cfg = LaserConfig.model_validate(overrides)
    _segment(scans[0], cfg)  # warm-up (imports, open3d initialisation)
    if args.profile:
        return _profile(scans, cfg, args.profile)
    wall, cpu, stages, voxels = [], [], {}, []
    for scan in scans:
        for _ in range(args.repeat):
            c0, w0 = time.process_time(), time.perf_counter()
            seg = _segment(scan, cfg)
            wall.append(time.perf_counter() - w0)
            cpu.append(time.process_time() - c0)
            for k, v in seg.timings.items():
                stages.setdefault(k, []).append(v)
        voxels.append(len(seg.pre.points))
    if args.process:
        out_process = _bench_process(scans, overrides, args.repeat)
    load = os.getloadavg()[0]
    out = {
        "source": args.source,
        "points_per_scan": int(np.median([np.isfinite(sc["points"]).all(axis=1).sum() for sc in scans])),
        "voxels_per_scan": int(np.median(voxels)),
        "voxel_size": cfg.preprocess.voxel_size,
        "runs": len(wall),
        "wall_median_s": round(float(np.median(wall)), 4),
        "wall_p95_s": round(float(np.percentile(wall, 95)), 4),
        "cpu_median_s": round(float(np.median(cpu)), 4),
        "cpu_p95_s": round(float(np.percentile(cpu, 95)), 4),
        "stage_median_s": {k: round(float(np.median(v)), 4) for k, v in stages.items()},  # wall; cpu_*: CPU
        "load_average_1min": round(load, 2),
        "cores": os.cpu_count(),
    }
    if args.process:
        out["process"] = out_process
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
