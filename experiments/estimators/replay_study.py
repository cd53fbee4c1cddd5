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


def run_one(bag: Path, obs_path: Path, config: SemslamConfig, estimators: list[str]):
    """The estimators on one recorded mission: (pipeline result, metrics.json's dict)."""
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
    result = run_pipeline(mission, ests, fes, view_estimator=estimators[0], frontend_process=False)
    return result, build_metrics(result, mission.metadata)


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
    return " | ".join(parts)


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
        _, metrics = run_one(bag, obs_path, config, estimators)
        out[bag.stem] = metrics
        print(line(bag.stem, metrics, estimators) + f" ({time.perf_counter() - t0:.0f} s)", flush=True)
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
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    (record if args.step == "record" else run)(args)


if __name__ == "__main__":
    main()
