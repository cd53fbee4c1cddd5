"""How far issue 9's acceptance numbers on the default tank mission (seed 0) carry to other seeds:
a thin caller of `semslam study` that prints, per seed, what that issue measured.

The study simulates each seed's tank mission (``--vary none``: as before issue 20, a seed draws the
pipe rack on the default lattice, the noise realisations and the DVL dropouts; ``--vary all`` also
draws the world's parameters, see semslam/sim/vary.py), compares dr / ekf / graph on it with the
demo's configuration, and writes ``OUT/study.json`` and ``OUT/report.html``. Printed per seed: ATE
RMSE and SE(3)-aligned ATE, the graph/EKF and graph/DR ATE ratios, graph objects and pipes, duplicates,
object median error and the recognition's SEM F1. The absolute ATE carries the offset that both SLAM
estimators inherit from the drift before the first landmark is seen; the aligned ATE shows the shape.

    python experiments/seed_study.py [--seeds 0-3] [--vary none] [--out experiments/out/seed_study] [--sim-config F]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from semslam.cli import app


def _line(m: dict) -> str:
    if m["status"] != "ok":
        return f"{m['mission']}: {m['status']}: {m['error']}"
    e = m["summary"]["estimators"]
    g, k, d = e["graph"], e["ekf"], e["dr"]
    f1 = m["summary"]["recognition_f1"].get("SEM")

    def f(v, fmt=".3f"):
        return "n/a" if v is None else format(v, fmt)

    def ratio(a, b):
        return None if a is None or not b else a / b

    return (
        f"{m['mission']}: ATE dr {f(d['ate_rmse_m'])} ekf {f(k['ate_rmse_m'])} graph {f(g['ate_rmse_m'])} | "
        f"aligned ekf {f(k['ate_rmse_se3_m'], '.4f')} graph {f(g['ate_rmse_se3_m'], '.4f')} | "
        f"graph/ekf {f(ratio(g['ate_rmse_m'], k['ate_rmse_m']), '.2f')}, "
        f"graph/dr {f(ratio(g['ate_rmse_m'], d['ate_rmse_m']), '.2f')} | "
        f"graph objects {g['n_objects']}, pipes {g['n_pipes']}, duplicates {g['landmark_duplicates']} "
        f"(ekf {k['landmark_duplicates']}), object median error {f(g['object_median_error_m'])} m, SEM F1 {f(f1)}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-3", help="simulator seeds, e.g. 0-3 or 0,5 (0: the default mission)")
    ap.add_argument(
        "--vary", default="none", help="what a seed draws besides layout and noise (see --help of semslam study)"
    )
    ap.add_argument("--out", type=Path, default=Path("experiments/out/seed_study"), help="the study folder (resumable)")
    ap.add_argument("--scheduler", help="a Dask scheduler's address (default: a LocalCluster)")
    ap.add_argument("--sim-config", help="YAML over the simulator's defaults (e.g. shorter missions)")
    args = ap.parse_args()
    cmd = ["study", "--scenario", "tank", "--seeds", args.seeds, "--vary", args.vary, "--out", str(args.out)]
    cmd += ["--scheduler", args.scheduler] if args.scheduler else []
    cmd += ["--sim-config", args.sim_config] if args.sim_config else []
    app(cmd, standalone_mode=False)
    for m in json.loads((args.out / "study.json").read_text())["missions"]:
        print(_line(m), flush=True)


if __name__ == "__main__":
    main()
