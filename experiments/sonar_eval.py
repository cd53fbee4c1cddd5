"""Evaluation of the sonar front-end on the simulated field (issue 8's acceptance), per seed and overall.

For each seed the field mission of ``semslam simulate field --seed N`` (``--vary all`` by default:
the seed draws the world too; ``--vary none``: the default world, as for issue 8's seeds 0–2; the
recognition threshold was calibrated on 3–5, see sonar_calibrate.py) is simulated in memory (or read
from ``--bag-dir/field<seed>.bag``) and run through dead reckoning and the graph with the sonar
front-end (the front-end sees the graph). Reported:

* structures (semslam.eval.structures): found only at the right place, judged relative to the
  estimated trajectory where the structure was seen (the registered pose moved by the navigation
  error of the patches it was fitted to: within 0.5 m and 5° of the truth, yaw modulo the
  symmetry); a registration at no right place is a false structure (``wrong place`` when on a true
  structure of its model) and its truth a miss; position error (absolute: the registered pose in
  the final map against the truth, with the navigation error where the structure was seen; and
  relative), median point-to-model distance after the final ICP, yaw error (absolute, relative);
  metrics.json's absolute judgement (1 m) is kept as ``structures_absolute``;
  ``--quick`` reports these alone (found / wrong place / missed / false per seed);
* swath disagreement (median |Δ depth| between overlapping patches of different passes, all common
  cells and textured cells): placed by dead reckoning (no registration at all), as navigated
  online, with the final graph estimate, and with the ground truth (the floor set by noise);
* consistency of the constraints against the truth: NEES of the swath registrations (in their
  informative directions) and of the structure observations (6 dof);
* world model bytes against the raw cloud; graph and dead-reckoning ATE; structures mapped as
  graph landmarks; front-end CPU time (recognition + registration, and in total).

    python experiments/sonar_eval.py [--seeds 0 1 2] [--vary all] [--quick] [--bag-dir DIR] [--out experiments/out/sonar_eval]
                                     [--frontend-config JSON]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from frontends.sonar import SonarFrontend
from frontends.sonar.summary import overlapping_pairs, swath_disagreement
from semslam.config import SemslamConfig
from semslam.estimators import create_estimator
from semslam.eval.outputs import build_metrics, write_outputs
from semslam.eval.structures import pose_at, structure_counts, structure_rows
from semslam.mission.measurements import GroundTruthPose
from semslam.pipeline import run_pipeline

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: tests.support

from tests.support.sonar_survey import true_structure_pose  # noqa: E402


def between_lines(traj, truth, lines, t0_ns: int, step_m: float = 0.5) -> dict:
    """Misalignment of neighbouring survey lines in an estimated trajectory: where two lines pass
    the same east coordinate, |(error on one) − (error on the other)| horizontally (what makes
    their swaths disagree), median and 95th percentile over every 0.5 m of shared east."""
    t = (np.asarray(traj.stamps) - t0_ns) * 1e-9
    tt = (np.asarray(truth.stamps) - t0_ns) * 1e-9
    P_true = np.stack([np.interp(t, tt, truth.positions[:, k]) for k in range(2)], 1)
    err = np.asarray(traj.positions)[:, :2] - P_true
    out = []
    for a, b in zip(lines, lines[1:]):
        lo = max(min(a["east_from_m"], a["east_to_m"]), min(b["east_from_m"], b["east_to_m"]))
        hi = min(max(a["east_from_m"], a["east_to_m"]), max(b["east_from_m"], b["east_to_m"]))
        e = np.arange(lo, hi + 1e-9, step_m)

        def when(line):
            f = (e - line["east_from_m"]) / (line["east_to_m"] - line["east_from_m"])  # noqa: B023
            return line["t_start_s"] + f * (line["t_end_s"] - line["t_start_s"])

        ta, tb = when(a), when(b)
        ok = (ta >= t[0]) & (ta <= t[-1]) & (tb >= t[0]) & (tb <= t[-1])
        ea = np.stack([np.interp(ta[ok], t, err[:, k]) for k in range(2)], 1)
        eb = np.stack([np.interp(tb[ok], t, err[:, k]) for k in range(2)], 1)
        out.append(np.linalg.norm(ea - eb, axis=1))
    d = np.concatenate(out) if out else np.zeros(0)
    return {
        "median_m": float(np.median(d)) if len(d) else None,
        "p95_m": float(np.percentile(d, 95)) if len(d) else None,
    }


def load(seed: int, bag_dir: Path | None, vary: str = "all"):
    """The field mission of ``seed``: read from ``bag_dir/field<seed>.bag`` if there, else simulated in
    memory with the configuration ``semslam simulate field --seed <seed> --vary <vary>`` uses."""
    if bag_dir is not None and (bag_dir / f"field{seed}.bag").exists():
        from semslam.mission.bag import read_mission

        return read_mission(bag_dir / f"field{seed}.bag")
    from semslam.sim.field_mission import simulate_field
    from semslam.sim.scenarios import resolve_config
    from semslam.sim.vary import parse_aspects

    return simulate_field(resolve_config("field", seed, parse_aspects(vary)))


def constraint_consistency(fe, mission) -> dict:
    gt = {m.stamp: m.matrix() for m in mission if isinstance(m, GroundTruthPose)}
    keys = np.array(sorted(gt))

    def true_pose(s):
        return gt[keys[min(np.searchsorted(keys, s), len(keys) - 1)]]

    swath, swath_dof, errs = [], 0, []
    for r in fe.swath_registrations:
        Ti, Tj = np.array(r["T_from"]), np.array(r["T_to"])
        need = (Ti @ np.linalg.inv(true_pose(r["stamp_from"])) @ true_pose(r["stamp"]))[:3, 3] - Tj[:3, 3]
        e = np.r_[r["shift"], r["depth"]] - need
        C = np.array(r["cov_W"])
        w, V = np.linalg.eigh(C[:2, :2])
        keep = w < 1.0
        e2 = V.T @ e[:2]
        swath.append(float(np.sum(e2[keep] ** 2 / w[keep])))
        swath_dof += int(keep.sum())
        errs.append(float(np.sqrt(np.sum(e2[keep] ** 2))))
    T_BS = mission.metadata.sensors["sonar"].T_BS
    struct = []
    for ks in fe.structures:
        T_true = true_structure_pose(mission, ks.model)
        sym = fe.library[ks.model].symmetry
        for stamp, _, T_SM, cov, _ in ks.history:
            T_t = np.linalg.inv(true_pose(stamp) @ T_BS) @ T_true
            best = None
            for k in range(sym):
                Rz = np.eye(4)
                a = 2 * np.pi * k / sym
                Rz[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
                d = np.linalg.inv(T_SM) @ T_t @ Rz
                xi = np.r_[Rotation.from_matrix(d[:3, :3]).as_rotvec(), d[:3, 3]]
                if best is None or np.linalg.norm(xi[:3]) < np.linalg.norm(best[:3]):
                    best = xi
            struct.append(float(best @ np.linalg.solve(cov, best)))
    return {
        "swath_registrations": len(swath),
        "swath_nees_per_dof": float(np.sum(swath) / swath_dof) if swath_dof else None,
        "swath_error_median_m": float(np.median(errs)) if errs else None,
        "structure_observations": len(struct),
        "structure_nees_mean_6dof": float(np.mean(struct)) if struct else None,
        "structure_nees_median_6dof": float(np.median(struct)) if struct else None,
    }


def evaluate(
    seed: int,
    bag_dir: Path | None,
    out_dir: Path,
    fe_config: dict | None = None,
    vary: str = "all",
    quick: bool = False,
) -> dict:
    t0 = time.time()
    mission = load(seed, bag_dir, vary)
    cfg = SemslamConfig()
    ests = [create_estimator("dr", mission.metadata, cfg), create_estimator("graph", mission.metadata, cfg)]
    fe = SonarFrontend(mission.metadata, fe_config or {})
    c0 = time.process_time()
    res = run_pipeline(mission, ests, [fe], view_estimator="graph")
    cpu = time.process_time() - c0
    metrics = build_metrics(res, mission.metadata)
    # judged relative to the estimated trajectory where each structure was seen (semslam.eval.structures);
    # metrics.json's absolute judgement is kept as structures_absolute
    relative = structure_rows(
        res.frontend_summaries["sonar"].metrics["structures"], mission.metadata.ground_truth, pose_at(res.truth)
    )
    registered = {
        # what the front-end registered and the truth, to re-score with another tolerance
        "registered": [
            {k: s[k] for k in ("model", "pose", "symmetry", "median_error_m", "fitness", "online")}
            for s in res.frontend_summaries["sonar"].metrics["structures"]
        ],
        "truth": [
            {"id": g.id, "model": g.model, "position": list(g.position), "orientation": list(g.orientation)}
            for g in mission.metadata.ground_truth.structures
        ],
        "seen_structures": list(mission.metadata.ground_truth.seen_structures or []),
        "unconfirmed": [
            {k: s[k] for k in ("model", "pose", "fitness", "median_error_m")}
            for s in res.frontend_summaries["sonar"].metrics.get("unconfirmed_structures", [])
        ],
    }
    if quick:  # the structures alone: no outputs, no navigation-only graph, no disagreement
        return {
            "seed": seed,
            "structures": relative,
            "structure_counts": structure_counts(relative),
            "structures_absolute": metrics["sonar"]["structures"],
            **registered,
            "ate_graph_m": metrics["estimators"]["graph"]["ate_rmse_m"],
            "ate_dr_m": metrics["estimators"]["dr"]["ate_rmse_m"],
            "graph_structures": metrics["estimators"]["graph"]["n_structures"],
            "rejected": metrics["sonar"]["swath_registration"]["rejected"],
            "pipeline_cpu_s": cpu,
            "wall_s": time.time() - t0,
        }
    write_outputs(out_dir / f"seed{seed}", cfg, res, metrics)
    # the same graph without the sonar's constraints: the "no registration" baseline
    nav_only = run_pipeline(mission, [create_estimator("graph", mission.metadata, cfg)], [])
    g0 = nav_only.results["graph"].trajectory
    g0_at = pose_at(g0, clip=True)
    sonar = metrics["sonar"]
    # swath disagreement under four placements of the same patches
    dr = res.results["dr"].trajectory
    dr_at = pose_at(dr, clip=True)
    gt = {m.stamp: m.matrix() for m in mission if isinstance(m, GroundTruthPose)}
    keys = np.array(sorted(gt))
    pairs = overlapping_pairs(fe)
    fe._begin(ests[1].view())  # the final graph estimate
    placements = {
        "dead_reckoning": lambda p: dr_at(p.anchor_stamp),
        "graph_without_sonar": lambda p: g0_at(p.anchor_stamp),
        "as_navigated": lambda p: p.T_nav,
        "final_graph": fe.place,
        "ground_truth": lambda p: gt[keys[min(np.searchsorted(keys, p.anchor_stamp), len(keys) - 1)]],
    }
    disagreement = {k: swath_disagreement(fe, f, pairs) for k, f in placements.items()}
    lines = mission.metadata.extras.get("trajectory", {}).get("lines", [])
    start_ns = int(round(mission.metadata.extras["simulator"]["config"]["start_time_s"] * 1e9)) if lines else 0
    misalignment = (
        {name: between_lines(res.results[name].trajectory, res.truth, lines, start_ns) for name in ("dr", "graph")}
        if lines and res.truth is not None
        else {}
    )
    if misalignment:
        misalignment["graph_without_sonar"] = between_lines(g0, res.truth, lines, start_ns)
    e = metrics["estimators"]
    row = {
        "seed": seed,
        "structures": relative,
        "structures_absolute": sonar["structures"],
        **registered,
        "all_found": all(s["found"] for s in relative if s["truth_id"] is not None),
        "false_structures": sum(1 for s in relative if s["truth_id"] is None),
        "disagreement": disagreement,
        "between_lines_misalignment": misalignment,
        "consistency": constraint_consistency(fe, mission),
        "swath_registration": sonar["swath_registration"],
        "world_model_bytes": sonar["world_model_bytes"],
        "raw_cloud_bytes": sonar["raw_cloud_bytes"],
        "world_model_fraction": sonar["world_model_fraction"],
        "ate_graph_m": e["graph"]["ate_rmse_m"],
        "ate_graph_online_m": e.get("graph_online", {}).get("ate_rmse_m"),
        "ate_dr_m": e["dr"]["ate_rmse_m"],
        "ate_graph_without_sonar_m": build_metrics(nav_only, mission.metadata)["estimators"]["graph"]["ate_rmse_m"],
        "graph_structures": e["graph"]["n_structures"],
        "graph_pipes": e["graph"]["n_pipes"],
        "structure_landmark_error_m": e["graph"].get("structure_median_error_m"),
        "frontend_recognition_registration_cpu_s": sonar["runtime_s"],
        "frontend_cpu_s": float(sum(v for k, v in sonar["timing_s"].items() if k.endswith("_s"))),
        "pipeline_cpu_s": cpu,
        "wall_s": time.time() - t0,
        "timing_s": sonar["timing_s"],
    }
    import pickle

    with open(out_dir / f"seed{seed}_frontend.pkl", "wb") as f:  # for diagnosis: constraints and their poses
        pickle.dump(
            {
                "swath_registrations": fe.swath_registrations,
                "swath_log": fe.windows.log,
                "structures": [(k.model, k.history, k.T_WM) for k in fe.structures],
                "rejection_log": fe.reobservation.log,
            },
            f,
        )
    return row


def table(rows: list[dict]) -> str:
    lines = [
        "| seed | structure | found | position err (m) | median pt-model (cm) | yaw err (°) |",
        "|---:|---|:---:|---:|---:|---:|",
    ]
    for r in rows:
        for s in r["structures"]:
            pe = "–" if s["position_error_m"] is None else f"{s['position_error_m']:.3f}"
            me = "–" if s["median_error_m"] is None else f"{100 * s['median_error_m']:.2f}"
            ye = "–" if s["yaw_error_deg"] is None else f"{s['yaw_error_deg']:.2f}"
            lines.append(f"| {r['seed']} | {s['model']} | {'yes' if s['found'] else 'NO'} | {pe} | {me} | {ye} |")
    lines += [
        "",
        "Swath disagreement: median |Δ depth| between overlapping passes (cm), patches placed by dead "
        "reckoning / the graph without the sonar's constraints / as navigated online (metrics.json's "
        "'before') / the final graph ('after') / the truth; between-line "
        "misalignment (cm) and ATE (m) of dead reckoning / graph without sonar / graph.",
        "",
        "| seed | all cells | textured cells | between-line misalignment | swath regs | NEES swath/dof, "
        "structure (6) | world model | ATE | landmarks | CPU rec+reg / front-end (s) |",
        "|---:|---|---|---|---:|---|---|---|---:|---|",
    ]
    for r in rows:
        d = r["disagreement"]
        order = ("dead_reckoning", "graph_without_sonar", "as_navigated", "final_graph", "ground_truth")
        f = lambda key: " / ".join("–" if d[k][key] is None else f"{100 * d[k][key]:.2f}" for k in order)  # noqa: B023, E731
        c = r["consistency"]
        ns = "–" if c["swath_nees_per_dof"] is None else f"{c['swath_nees_per_dof']:.2f}"
        nt = "–" if c["structure_nees_mean_6dof"] is None else f"{c['structure_nees_mean_6dof']:.1f}"
        b = r.get("between_lines_misalignment") or {}
        mis = " / ".join(f"{100 * b[k]['median_m']:.1f}" for k in ("dr", "graph_without_sonar", "graph") if k in b)
        lines.append(
            f"| {r['seed']} | {f('median_m')} | {f('textured_median_m')} | {mis} | "
            f"{r['swath_registration']['accepted']} | {ns}, {nt} | "
            f"{r['world_model_bytes'] / 1e3:.0f} kB = {100 * r['world_model_fraction']:.2f} % | "
            f"{r['ate_dr_m']:.3f} / {r['ate_graph_without_sonar_m']:.3f} / {r['ate_graph_m']:.3f} | "
            f"{r['graph_structures']} | "
            f"{r['frontend_recognition_registration_cpu_s']:.1f} / {r['frontend_cpu_s']:.1f} |"
        )
    return "\n".join(lines)


def structure_table(rows: list[dict]) -> str:
    """Per seed: structures found (registered at the right place), registered at the wrong place,
    missed, false (no truth of the model near)."""
    lines = ["| seed | found | wrong place | missed | false | structures (model: position err m / yaw err °) |"]
    lines.append("|---:|---:|---:|---:|---:|---|")
    for r in rows:
        st = r["structures"]
        true = [s for s in st if s["truth_id"] is not None]
        found = sum(bool(s["found"]) for s in true)
        wrong = sum(bool(s.get("wrong_place")) for s in st if s["truth_id"] is None)
        false = sum(1 for s in st if s["truth_id"] is None and not s.get("wrong_place"))
        desc = ", ".join(
            f"{s['model']}{'' if s['found'] else ' (miss)' if s['truth_id'] is not None else ' (wrong)' if s.get('wrong_place') else ' (false)'}"
            + (
                f": {s['position_error_m']:.2f}/{s['yaw_error_deg']:.1f}"
                + (
                    f" (rel {s['relative_position_error_m']:.2f}/{s['relative_yaw_error_deg']:.1f})"
                    if s.get("relative_position_error_m") is not None
                    else ""
                )
                if s.get("position_error_m") is not None and s.get("yaw_error_deg") is not None
                else ""
            )
            for s in st
        )
        lines.append(f"| {r['seed']} | {found}/{len(true)} | {wrong} | {len(true) - found} | {false} | {desc} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--bag-dir", type=Path, default=None)
    ap.add_argument(
        "--vary",
        default="all",
        help="what the seed draws, as `semslam simulate field --vary` (all: the world too; none: noise only)",
    )
    ap.add_argument("--out", type=Path, default=Path("experiments/out/sonar_eval"))
    ap.add_argument(
        "--frontend-config",
        type=json.loads,
        default=None,
        help='JSON overrides of frontends.sonar, e.g. \'{"recognition": {"enabled": false}}\' '
        "(swath registration alone: what it does to the disagreement without structures)",
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="structures only (per seed: found / wrong place / missed), no outputs or navigation-only graph",
    )
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for seed in args.seeds:
        row = evaluate(seed, args.bag_dir, args.out, args.frontend_config, args.vary, args.quick)
        rows.append(row)
        (args.out / f"seed{seed}.json").write_text(json.dumps(row, indent=1, default=float))
        print(f"seed {seed}: {row['wall_s']:.0f} s, CPU {row['pipeline_cpu_s']:.0f} s", flush=True)
    if args.quick:
        md = structure_table(rows)
        (args.out / "structures.md").write_text(md + "\n")
        print(md)
        return
    found = [s for r in rows for s in r["structures"] if s["truth_id"] is not None]
    ok = [s for s in found if s["found"]]
    overall = {
        "seeds": args.seeds,
        "structures_found": f"{len(ok)}/{len(found)}",
        "false_structures": sum(r["false_structures"] for r in rows),
        "median_point_to_model_cm_max": 100 * max(s["median_error_m"] for s in ok) if ok else None,
        "yaw_error_deg_max": max(s["yaw_error_deg"] for s in ok) if ok else None,
        "position_error_m_median": float(np.median([s["position_error_m"] for s in ok])) if ok else None,
        "disagreement_median_cm": {
            k: float(np.median([100 * r["disagreement"][k]["median_m"] for r in rows])) for k in rows[0]["disagreement"]
        },
        "textured_disagreement_median_cm": {
            k: float(np.median([100 * r["disagreement"][k]["textured_median_m"] for r in rows]))
            for k in rows[0]["disagreement"]
        },
        "world_model_fraction_max": max(r["world_model_fraction"] for r in rows),
        "recognition_registration_cpu_s_median": float(
            np.median([r["frontend_recognition_registration_cpu_s"] for r in rows])
        ),
    }
    (args.out / "summary.json").write_text(json.dumps({"overall": overall, "seeds": rows}, indent=1, default=float))
    md = table(rows)
    (args.out / "table.md").write_text(md + "\n\n" + json.dumps(overall, indent=1) + "\n")
    print(md)
    print(json.dumps(overall, indent=1))


if __name__ == "__main__":
    main()
