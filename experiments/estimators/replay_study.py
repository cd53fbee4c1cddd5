"""Estimators on recorded front-end observations: simulate a scenario's seeds and run its front-end
once (``record``), then feed those observations to the estimators as often as needed (``run``), so that
only the estimators differ between two runs and an iteration costs the estimators' time alone.

    python experiments/estimators/replay_study.py record --seeds 100-109 --loops 1.5 --cache DIR
    python experiments/estimators/replay_study.py run --seeds 100-109 --cache DIR [--config F] [--out F.json]

``record`` writes DIR/<scenario>-seed<N>.bag (simulated as `semslam study --scenario` would, every
aspect varied) and DIR/<scenario>-seed<N>.obs.pkl (the front-end's observations by stamp, its
summary); ``run`` prints one line per mission and, with ``--out``, writes every mission's
metrics.json block of the estimators (semslam.eval.metrics) as one JSON file.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import BaseModel

from semslam.config import SemslamConfig, load_config
from semslam.mission.measurements import Measurement, PointCloud, SonarSwath
from semslam.registry import Frontend, FrontendSummary


class _NoConfig(BaseModel):
    pass


class RecordedFrontend(Frontend):
    """Hands over, at each scan or swath, the observations recorded for its stamp, and the recorded
    summary (with its last observations) at the end."""

    name: ClassVar[str] = "recorded"
    consumes: ClassVar[tuple] = (PointCloud, SonarSwath)
    config_model: ClassVar[type] = _NoConfig

    def __init__(self, name: str, observations: dict, summary: FrontendSummary | None):
        self.name = name
        self.observations = observations
        self.summary = summary

    def process(self, measurement: Measurement, view=None) -> list:
        return list(self.observations.get(measurement.stamp, []))

    def finish(self, view=None):
        return self.summary


def _paths(cache: Path, scenario: str, seed: int) -> tuple[Path, Path]:
    stem = cache / f"{scenario}-seed{seed}"
    return stem.with_suffix(".bag"), stem.with_suffix(".obs.pkl")


def _config(path: str | None, scenario: str) -> SemslamConfig:
    if path is not None:
        return load_config(path)
    if scenario == "tank":
        from semslam.demo import demo_config

        return demo_config()
    return SemslamConfig()


def record(args) -> None:
    from semslam.compare import default_frontends
    from semslam.estimators import create_estimator
    from semslam.mission.bag import read_mission
    from semslam.pipeline import run_pipeline
    from semslam.registry import create_frontends
    from semslam.sim.scenarios import resolve_config, simulate_to_bag
    from semslam.sim.vary import ASPECTS

    config = _config(args.config, args.scenario)
    overrides = {"trajectory__loops": args.loops} if args.loops else {}
    for seed in args.seeds:
        bag, obs_path = _paths(args.cache, args.scenario, seed)
        if obs_path.exists():
            continue
        t0 = time.perf_counter()
        if not bag.exists():
            sim = resolve_config(args.scenario, seed, ASPECTS, **overrides)
            simulate_to_bag(args.scenario, sim, bag)
        mission = read_mission(bag, config.reader)
        names = default_frontends(mission.metadata)
        fes = create_frontends(names, mission.metadata, config.frontends)
        dr = create_estimator("dr", mission.metadata, config)
        result = run_pipeline(mission, [dr], fes, frontend_workers=1)
        by_stamp: dict[str, dict[int, list]] = defaultdict(lambda: defaultdict(list))
        summaries = dict(result.frontend_summaries)
        last_word = {n: len(s.observations or []) for n, s in summaries.items()}
        records = list(result.observations)
        for name, n in last_word.items():  # the summary's observations are fed again from it
            if n:
                mine = [i for i, r in enumerate(records) if r.frontend == name]
                for i in reversed(mine[-n:]):
                    del records[i]
        for r in records:
            by_stamp[r.frontend][r.stamp].append(r.observation)
        for s in summaries.values():
            s.files = {}  # writers (closures) do not pickle and are not needed here
        payload = {"observations": {k: dict(v) for k, v in by_stamp.items()}, "summaries": summaries, "names": names}
        obs_path.write_bytes(pickle.dumps(payload))
        print(f"{bag.stem}: {len(records)} observations in {time.perf_counter() - t0:.0f} s", flush=True)


def run_one(bag: Path, obs_path: Path, config: SemslamConfig, estimators: list[str], still_test: int | None = None):
    """The estimators on one recorded mission: (pipeline result, metrics.json's dict, the mission's metadata);
    with ``still_test``, the DVL's zero-velocity test at the start (graph_vs_ekf.held_while_still)."""
    from semslam.compare import estimators_input
    from semslam.estimators import create_estimator
    from semslam.eval.outputs import build_metrics
    from semslam.mission.bag import read_mission
    from semslam.pipeline import run_pipeline

    payload = pickle.loads(obs_path.read_bytes())
    mission = read_mission(bag, config.reader)
    fes = [
        RecordedFrontend(n, payload["observations"].get(n, {}), payload["summaries"].get(n)) for n in payload["names"]
    ]
    ests = [create_estimator(n, mission.metadata, config) for n in estimators]
    if still_test is not None:
        from graph_vs_ekf import held_while_still

        mission, _ = held_while_still(mission, still_test)
    seen = estimators_input(mission, config)  # as compare feeds them (the start at rest)
    result = run_pipeline(seen, ests, fes, view_estimator=estimators[0], frontend_process=False)
    return result, build_metrics(result, mission.metadata), mission.metadata


def _fmt(v, spec=".3f") -> str:
    return "-" if v is None else format(v, spec)


def line(name: str, metrics: dict, estimators: list[str]) -> str:
    gt = metrics["mission"]
    parts = [f"{name} (obj {gt['gt_objects']}, pipes {gt['gt_pipes']})"]
    for est in estimators:
        e = metrics["estimators"][est]
        parts.append(
            f"{est}: ATE {_fmt(e['ate_rmse_m'])}/{_fmt(e.get('ate_rmse_pos_yaw_m'))}/{_fmt(e.get('ate_rmse_se3_m'))} "
            f"obj {e['n_objects']} d{e.get('object_duplicates')} m{e.get('object_missed')} f{e.get('object_false')} "
            f"pipes {e['n_pipes']}/{e.get('pipe_seen')} d{e.get('pipe_duplicates')} m{e.get('pipe_missed')} "
            f"f{e.get('pipe_false')} err o/p {_fmt(e.get('object_median_error_m'), '.4f')}/"
            f"{_fmt(e.get('pipe_median_error_m'), '.4f')} NEES {_fmt(e['nees_mean'], '.2f')}"
            f"{'' if e.get('nees_in_band') else '!'}{_fmt((e.get('nees_band95') or [None])[0], '.1f')}-"
            f"{_fmt((e.get('nees_band95') or [None, None])[1], '.1f')}"
        )
        al = e.get("map_aligned")
        if al:
            parts[-1] += (
                f" [aligned: obj d{al['object_duplicates']} m{al['object_missed']} f{al['object_false']} "
                f"pipes d{al['pipe_duplicates']} m{al['pipe_missed']} f{al['pipe_false']} err o/p "
                f"{_fmt(al['object_median_error_m'], '.4f')}/{_fmt(al['pipe_median_error_m'], '.4f')}]"
            )
    return " | ".join(parts)


def twins_and_misses(landmarks, truth, gate_m: float = 0.5) -> list[str]:
    """What a map got wrong, one line each: two estimates of one true object or pipe (how far apart,
    views each), true pipes seen but not mapped (length; the nearest estimate's cost)."""
    from semslam.eval.metrics import match_landmarks

    rows = []
    for kind, gts in (("object", truth.objects), ("pipe", truth.pipes)):
        mine = [lm for lm in landmarks if lm.kind == kind]
        if not mine:
            continue
        matches, _ = match_landmarks(mine, truth, gate_m)
        by_truth = defaultdict(list)
        for lm in mine:
            if kind == "object":
                d = [float(np.linalg.norm(lm.position - np.array(g.position))) for g in gts]
            else:
                d = [_pipe_cost(lm, g) for g in gts]
            j = int(np.argmin(d))
            if d[j] <= gate_m:
                by_truth[gts[j].id].append((lm, d[j]))
        for tid, ests in by_truth.items():
            if len(ests) > 1:
                at = [lm.position if kind == "object" else 0.5 * (lm.p + lm.q) for lm, _ in ests]
                rows.append(
                    f"twin {kind} truth {tid}: estimates {[lm.id for lm, _ in ests]} errors "
                    f"{[round(e, 3) for _, e in ests]} views {[lm.n_observations for lm, _ in ests]} "
                    f"apart {np.linalg.norm(at[0] - at[1]):.3f}"
                )
        seen = truth.seen_pipes if kind == "pipe" else truth.seen_objects
        seen = {g.id for g in gts} if seen is None else set(seen)
        got = {m.truth_id for m in matches}
        for g in gts:
            if g.id in seen and g.id not in got:
                extra = f" length {np.linalg.norm(np.subtract(g.q, g.p)):.2f}" if kind == "pipe" else f" {g.cls}"
                rows.append(f"missed {kind} truth {g.id}{extra}")
    return rows


def _pipe_cost(lm, g) -> float:
    p, q = np.array(g.p), np.array(g.q)
    d = (q - p) / np.linalg.norm(q - p)
    L = np.linalg.norm(q - p)
    cost = 0.0
    for e in (lm.p, lm.q):
        t = (e - p) @ d
        cost += 0.5 * np.linalg.norm(e - p - t * d) + 0.5 * max(0.0, -t, t - L)
    return float(cost)


def run(args) -> None:
    config = _config(args.config, args.scenario)
    estimators = args.estimators.split(",")
    out = {}
    for seed in args.seeds:
        bag, obs_path = _paths(args.cache, args.scenario, seed)
        if not obs_path.exists():
            print(f"{bag.stem}: not recorded", file=sys.stderr)
            continue
        t0 = time.perf_counter()
        result, metrics, metadata = run_one(bag, obs_path, config, estimators, args.still_test)
        out[bag.stem] = metrics
        print(line(bag.stem, metrics, estimators) + f" ({time.perf_counter() - t0:.0f} s)", flush=True)
        if args.dump:
            keep = {n: (r.trajectory, r.landmarks) for n, r in result.results.items()}
            (Path(args.dump) / f"{bag.stem}.result.pkl").write_bytes(pickle.dumps((keep, result.truth)))
        if args.detail:
            truth = metadata.ground_truth
            for est in estimators:
                for row in twins_and_misses(result.results[est].landmarks, truth):
                    print(f"    {est}: {row}", flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1, default=float))


def main() -> None:
    from semslam.study.plan import parse_seeds

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("step", choices=("record", "run"))
    ap.add_argument("--scenario", default="tank")
    ap.add_argument("--seeds", type=parse_seeds, default=parse_seeds("100-109"))
    ap.add_argument("--cache", type=Path, required=True, help="where the bags and observations are kept")
    ap.add_argument("--loops", type=float, help="record: loops of the tank trajectory (default: the seed's)")
    ap.add_argument("--config", help="semslam configuration YAML (default: the study's for the scenario)")
    ap.add_argument("--estimators", default="graph,ekf")
    ap.add_argument("--out", help="run: write the metrics of every mission here (JSON)")
    ap.add_argument("--dump", help="run: pickle each mission's trajectories, maps and true trajectory here")
    ap.add_argument("--still-test", type=int, help="run: the DVL's zero-velocity test at the start over N readings")
    ap.add_argument("--detail", action="store_true", help="run: list twins and missed landmarks per estimator")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    (record if args.step == "record" else run)(args)


if __name__ == "__main__":
    main()
