"""Memory of `semslam run --estimator graph` on a long simulated survey (issue 26; not a test).

The mission: the tank simulator circling the pipe rack for ``--hours`` (default 2: 46 loops), with
its DVL (5 Hz), AHRS (20 Hz), depth (8 Hz), ground truth (20 Hz) and a laser of 34×30 rays at 0.5 Hz
(the oracle front-end, ground truth plus noise, misses and false positives, needs only the scans'
stamps; full laser scans would make a 2-hour bag of ~9 GB). It is simulated once by
`semslam simulate` in a process of its own, into ``--work``.

The run is the real command, ``run MISSION --estimator graph --frontends oracle``, in a fresh
process (so that its memory is the run's alone), with an observer of the pipeline that samples,
every ``--every`` seconds of mission time: the resident set size, and the graph's factor counts:
every factor committed (the graph keeps them all only for the batch re-optimisation, ``--batch``),
the factors the session still holds (``kept_factors``: all of them with ``--batch``, else none), the
factors of the smoothing window (what iSAM2 holds: ``graph.window_s``, 600 s by default) and
iSAM2's own factor slots. The factor counts are read from the estimator's parts
(``GraphEstimator.session``, ``.keyframes``, ``.map``): a measurement of the graph back-end as it is.

``--tracemalloc`` also traces Python's allocations from the pipeline's first step (numpy's included,
GTSAM's C++ ones not; the run is ~2× slower) and lists the allocation sites (by line, then by call path) of what was
allocated after the window filled (1.5 × window_s, its first slide) and is still held when the
estimator finishes: what grows with the mission.

After the mission, the RSS and the peak RSS so far are taken at each stage of the run's end
(``end_phases``: the mission streamed, the estimator's result, the metrics, the outputs written):
which of them makes the peak.

``run`` keeps no observation: of each labelled object observation, the numbers the recognition
tables read (``PipelineResult.labelled``, ~100 bytes a view).

Run: ``python experiments/long_survey_memory.py [--hours 2] [--work DIR] [--out F.json] [--tracemalloc]
[--config F.yaml] [--batch]`` (a shorter ``graph.window_s`` in F shows the slope after the
window filled on a shorter survey); also ``F.png`` (memory and factors against mission time) and
``F.samples.jsonl`` (each sample as it is taken: what a run stopped early leaves). Measured numbers
go in experiments/speed/README.md, not here.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

# The results a memory change must leave as they were (metrics.json's graph block).
METRICS = (
    "ate_rmse_m",
    "ate_max_m",
    "rpe_rmse_m",
    "landmark_median_error_m",
    "object_median_error_m",
    "pipe_median_error_m",
    "n_objects",
    "n_pipes",
    "nees_mean",
    "landmark_duplicates",
    "landmark_spurious",
)
LOOP_S = 156.6667  # TrajectoryConfig.loop_period_s: one loop around the rack


def simulate(hours: float, work: Path) -> Path:
    bag = work / f"tank-{hours:g}h.bag"
    if bag.exists():
        return bag
    work.mkdir(parents=True, exist_ok=True)
    cfg = work / f"tank-{hours:g}h.yaml"
    cfg.write_text(
        f"trajectory:\n  duration_s: {hours * 3600:.1f}\nlaser:\n  resolution: [34, 30]\nground_truth:\n  rate_hz: 20\n"
    )
    semslam = Path(sys.executable).with_name("semslam")
    t0 = time.perf_counter()
    subprocess.run([str(semslam), "simulate", "tank", "--sim-config", str(cfg), "--out", str(bag)], check=True)
    print(f"simulated in {time.perf_counter() - t0:.0f} s: {bag} ({bag.stat().st_size / 1e6:.0f} MB)", flush=True)
    return bag


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


class MemoryProbe:
    """A pipeline observer: every ``every_s`` of mission time, the RSS and the graph's factor counts."""

    def __init__(self, every_s: float, stream: Path, count: bool = False, trace: bool = False):
        self.every_ns = int(every_s * 1e9)
        self.trace = trace  # trace Python's allocations from the pipeline's first step (not the mission check)
        self.stream = stream.open("w")
        self.count = count  # also count the observation and ground-truth objects alive (~0.5 s a sample)
        self.graph = None  # the estimator, captured when the command creates it
        self.rows: list[dict] = []
        self.filled = self.end = None  # tracemalloc snapshots: once the window has filled, at the end
        self.filled_mb = self.end_mb = None  # the traced memory then
        self._start = self._next = self.last = None
        self._t0 = time.perf_counter()

    def step(self, stamp, measurement, observations, views) -> None:
        if self._start is None:
            if self.trace:
                import tracemalloc

                tracemalloc.start(12)
            self._start = self._next = stamp
        self.last = stamp
        if stamp >= self._next:
            self._next += self.every_ns
            self.rows.append(self.sample(stamp))
            self.stream.write(json.dumps(self.rows[-1]) + "\n")
            self.stream.flush()

    def sample(self, stamp: int) -> dict:
        import tracemalloc

        g = self.graph
        t_s = (stamp - self._start) * 1e-9
        if tracemalloc.is_tracing() and self.filled is None and t_s >= 1.5 * (g.cfg.window_s or 0):
            self.filled = tracemalloc.take_snapshot()
            self.filled_mb = tracemalloc.get_traced_memory()[0] / 1e6
        return {
            "traced_mb": tracemalloc.get_traced_memory()[0] / 1e6 if tracemalloc.is_tracing() else None,
            "t_s": t_s,
            "wall_s": time.perf_counter() - self._t0,
            "rss_mb": rss_mb(),
            "factors_created": getattr(g.session, "n_committed", len(g.session.factors)),  # before: all kept
            "kept_factors": len(g.session.factors),
            "window_factors": len(g.session.window),
            "isam_factor_slots": g.session.isam.getFactorsUnsafe().size(),
            "keyframes": len(g.keyframes.stamps),
            "landmarks": len(g.map),
            **(live_objects() if self.count else {}),
        }


class EndPhases:
    """The RSS and the peak RSS so far after each stage of the run's end (the peak is reached after
    the mission: which stage raised it)."""

    def __init__(self):
        self.rows: list[dict] = []

    def mark(self, phase: str) -> None:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6  # ru_maxrss: KiB
        self.rows.append({"phase": phase, "rss_mb": rss_mb(), "peak_rss_mb": peak})

    def after(self, module, name: str, phase: str) -> None:
        """Mark ``phase`` after each call of ``module.name`` (looked up there at call time by the command)."""
        fn = getattr(module, name)

        def marked(*args, **kwargs):
            out = fn(*args, **kwargs)
            self.mark(phase)
            return out

        setattr(module, name, marked)


def growth(end, filled, by: str, n: int) -> list[dict]:
    """The ``n`` allocation sites (``by``: "lineno" or "traceback") that grew most from ``filled`` to ``end``."""
    rows = []
    for st in sorted(end.compare_to(filled, by), key=lambda st: -st.size_diff)[:n]:
        frames = [f"{f.filename.split('site-packages/')[-1].split('replay/')[-1]}:{f.lineno}" for f in st.traceback]
        rows.append({"mb": st.size_diff / 1e6, "count": st.count_diff, "where": frames[-6:]})
    return rows


def live_objects() -> dict:
    """The observations (labelled ones too) and ground-truth poses alive in this process."""
    import gc

    from semslam.mapping.book import labelled
    from semslam.mission.measurements import GroundTruthPose
    from semslam.observations import Observation

    obs = [o for o in gc.get_objects() if isinstance(o, (Observation, GroundTruthPose))]
    return {
        "live_observations": sum(isinstance(o, Observation) for o in obs),
        "live_labelled": sum(isinstance(o, Observation) and labelled(o) for o in obs),
        "live_truth_poses": sum(isinstance(o, GroundTruthPose) for o in obs),
    }


def measure(bag: Path, every_s: float, out_json: Path, trace: bool, count: bool, extra: list[str]) -> None:
    """In this process: the `run` command on ``bag`` with a MemoryProbe; the samples to ``out_json``."""
    import tracemalloc

    import semslam.estimators
    import semslam.eval.outputs
    from semslam.cli import app
    from semslam.pipeline import observed_by

    probe = MemoryProbe(every_s, out_json.with_suffix(".samples.jsonl"), count, trace)
    create = semslam.estimators.create_estimator

    def capture(*args, **kwargs):
        probe.graph = est = create(*args, **kwargs)
        finish = est.finish

        def finish_after_snapshot():  # what the estimator holds before it assembles its result
            if trace:
                probe.end, probe.end_mb = tracemalloc.take_snapshot(), tracemalloc.get_traced_memory()[0] / 1e6
            phases.mark("mission streamed")
            result = finish()
            phases.mark("estimator finished (marginals, map, histories)")
            return result

        est.finish = finish_after_snapshot
        return est

    semslam.estimators.create_estimator = capture
    phases = EndPhases()
    phases.after(semslam.eval.outputs, "build_metrics", "metrics built")
    phases.after(semslam.eval.outputs, "write_staged", "outputs written")
    out_dir = out_json.with_suffix(".run")
    t0 = time.perf_counter()
    with observed_by(probe):
        app(
            ["run", str(bag), "-e", "graph", "--frontends", "oracle", "--out", str(out_dir), "--overwrite", *extra],
            standalone_mode=False,
        )
    metrics = json.loads((out_dir / "metrics.json").read_text())
    grew = {}
    if probe.filled is not None:  # the end snapshot is taken before the estimator's finish: what it holds
        grew = {by: growth(probe.end, probe.filled, by, 12) for by in ("lineno", "traceback")}
        grew["traced_mb"] = {"filled": probe.filled_mb, "end": probe.end_mb}
    result = {
        "mission": str(bag),
        "wall_s": time.perf_counter() - t0,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6,  # ru_maxrss: KiB
        "final": probe.sample(probe.last),
        "samples": probe.rows,
        "window_s": probe.graph.cfg.window_s,
        "graph": metrics["estimators"]["graph"],
        "growth_after_window_filled": grew,
        "end_phases": phases.rows,
    }
    out_json.write_text(json.dumps(result, indent=1))


def slope_mb_per_min(samples: list[dict]) -> float:
    """Least-squares slope of the RSS against mission time."""
    import numpy as np

    t = np.array([r["t_s"] / 60 for r in samples])
    return float(np.polyfit(t, [r["rss_mb"] for r in samples], 1)[0])


def plot(result: dict, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = result["samples"]
    t = [r["t_s"] / 60 for r in s]
    fig, (a, b) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    a.plot(t, [r["rss_mb"] for r in s])
    a.set_ylabel("RSS (MB)")
    a.set_title(f"semslam run -e graph, {t[-1]:.0f} min of mission: peak RSS {result['peak_rss_mb']:.0f} MB")
    for key in ("factors_created", "kept_factors", "window_factors", "isam_factor_slots"):
        b.plot(t, [r.get(key, 0) for r in s], label=key.replace("_", " "))
    b.set_ylabel("factors")
    b.set_xlabel("mission time (min)")
    b.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=100)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=2.0)
    ap.add_argument("--work", type=Path, default=Path("runs/long_survey"))
    ap.add_argument("--every", type=float, default=60.0, help="mission seconds between samples")
    ap.add_argument("--out", type=Path, default=None, help="JSON of the samples (and a PNG beside it)")
    ap.add_argument("--tracemalloc", action="store_true", help="also trace Python's allocations (~2x slower)")
    ap.add_argument("--config", type=Path, default=None, help="semslam configuration YAML for the run")
    ap.add_argument("--batch", action="store_true", help="run with --batch (keeps every factor)")
    ap.add_argument("--count", action="store_true", help="count the observation and truth objects alive per sample")
    ap.add_argument("--measure", type=Path, default=None, help=argparse.SUPPRESS)  # the run's own process
    args = ap.parse_args()
    extra = (["--config", str(args.config)] if args.config else []) + (["--batch"] if args.batch else [])
    if args.measure is not None:
        measure(args.measure, args.every, args.out, args.tracemalloc, args.count, extra)
        return
    bag = simulate(args.hours, args.work)
    out = args.out or args.work / f"memory-{args.hours:g}h.json"
    cmd = [sys.executable, __file__, "--measure", str(bag), "--every", str(args.every), "--out", str(out)]
    cmd += ["--tracemalloc"] if args.tracemalloc else []
    cmd += ["--count"] if args.count else []
    cmd += (["--config", str(args.config)] if args.config else []) + (["--batch"] if args.batch else [])
    subprocess.run(cmd, check=True)
    result = json.loads(out.read_text())
    plot(result, out.with_suffix(".png"))
    print(
        f"{'t (min)':>8} {'RSS MB':>8} {'traced':>7} {'factors':>8} {'kept':>8} {'window':>7} {'iSAM2':>7} "
        f"{'keyframes':>9} {'landmarks':>9} {'live obs':>8} {'labelled':>8} {'truth':>6}"
    )
    for r in result["samples"][:: max(1, len(result["samples"]) // 24)] + [result["final"]]:
        print(
            f"{r['t_s'] / 60:8.1f} {r['rss_mb']:8.0f} {r['traced_mb'] or 0:7.0f} {r['factors_created']:8d} "
            f"{r['kept_factors']:8d} {r['window_factors']:7d} {r['isam_factor_slots']:7d} {r['keyframes']:9d} "
            f"{r['landmarks']:9d} {r.get('live_observations', ''):>8} {r.get('live_labelled', ''):>8} "
            f"{r.get('live_truth_poses', ''):>6}"
        )
    grew = result["growth_after_window_filled"]
    if grew:
        mb = grew["traced_mb"]
        print(f"traced Python memory {mb['filled']:.1f} MB when the window filled, {mb['end']:.1f} MB at the end")
    for by in ("lineno", "traceback") if grew else ():
        print(f"grew most after the window filled, by {by}:")
        for row in grew[by]:
            print(f"  {row['mb']:+7.2f} MB in {row['count']:+8d} blocks: {' <- '.join(reversed(row['where']))}")
    marks = [m for m in (15, 30, 60, 90, 120) if m * 60 <= result["samples"][-1]["t_s"]]
    if marks:  # the sample nearest each mark
        near = [min(result["samples"], key=lambda r, m=m: abs(r["t_s"] - 60 * m)) for m in marks]
        print("RSS at " + ", ".join(f"{r['t_s'] / 60:.0f} min {r['rss_mb']:.0f} MB" for r in near))
    fill_s = 1.5 * result["window_s"] if result.get("window_s") else None
    if fill_s is not None:
        after = [r for r in result["samples"] if r["t_s"] >= fill_s]
        if len(after) >= 2:
            slope = slope_mb_per_min(after)
            print(f"RSS after the window filled ({fill_s / 60:.1f} min of mission on): {slope:+.2f} MB/min")
    for row in result.get("end_phases", []):
        print(f"after {row['phase']}: RSS {row['rss_mb']:.0f} MB, peak so far {row['peak_rss_mb']:.0f} MB")
    g = result["graph"]
    print(
        f"peak RSS {result['peak_rss_mb']:.0f} MB; wall {result['wall_s']:.0f} s; graph ATE {g['ate_rmse_m']}, "
        f"{g['n_objects']} objects, {g['n_pipes']} pipes; update median {g['update_ms_median']} ms, "
        f"p95 {g['update_ms_p95']} ms; {out}, {out.with_suffix('.png')}"
    )
    print({k: g.get(k) for k in METRICS})


if __name__ == "__main__":
    main()
