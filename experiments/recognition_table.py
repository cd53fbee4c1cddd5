"""The recognition tables of Vallicrosa et al. 2021 (Tables 3–4) and Himri et al. 2018.

Two parts, run separately or together:

``--syn``  The recogniser on synthetic views of the CAD library: the view database (cached), its
           leave-one-out accuracy (Himri et al.: chi-square NN and RBF SVM, per descriptor), and
           the SYN confusion matrix on held-out views (random viewpoints, distances 1–4 m and
           rolls, fresh 5 mm range noise — none of them in the database), which the recogniser
           then uses as P(Z | X). Written to ``OUT/syn_confusion.json``.

``--records FILE``  The DESC, BAYS and SEM stages on a mission's object observations. FILE is JSON
           Lines, one observation per line, in time order::

               {"true_class": "Elbow", "likelihood": {"Ball-Valve": 0.03, "Elbow": 0.8, ...},
                "landmark_id": 12, "configuration": 3}

           (``landmark_id``: the graph's global id, null if never associated; ``configuration``:
           the pipe configuration 1–4 seen in that scan, or null). The SYN stage is taken from
           ``--syn-confusion`` (default: the one ``--syn`` just computed).

``--synthetic N``  Instead of a mission, N landmarks observed by a simulated recogniser whose
           errors follow the SYN confusion — a check of the stage logic end to end.

``--tank``  The simulated tank mission (``semslam.sim``, ``--seed``) with oracle segmentation and
           oracle ids: every scan is ray-cast with the simulator's laser (labelled rays), each
           object's own hits (≥ ``--min-points``) are recognised by the default recogniser, the
           landmark id is the object's id, and the configuration is that of the object's pipes
           with at least ``--min-points`` hits in the scan. This measures the recogniser and the
           fusion on the real geometry (occlusions, partial views, ranges) without the laser
           segmentation's errors; the lead's run with the laser front-end and graph ids writes
           ``--records`` instead.

Output: a Markdown table on stdout, and ``OUT/recognition.json`` in the ``metrics.json``
"recognition" layout ({stage: {accuracy, precision, recall, f1, confusion, per_class, ...}}).

    python experiments/recognition_table.py --syn --out runs/recognition
    python experiments/recognition_table.py --records obs.jsonl --syn-confusion runs/recognition/syn_confusion.json
    python experiments/recognition_table.py --tank --max-scans 60
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from semslam.semantics.metrics import ObservationRecord, classification_metrics, format_table, recognition_metrics


def read_records(path: Path) -> list[ObservationRecord]:
    records = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            d = json.loads(line)
            records.append(
                ObservationRecord(d["true_class"], d["likelihood"], d.get("landmark_id"), d.get("configuration"))
            )
        except (json.JSONDecodeError, KeyError) as exc:
            sys.exit(f"{path}:{n}: not an observation record ({exc})")
    return records


def syn_stage(args) -> dict:
    from frontends.laser.recognition.matching import ChiSquareNN, leave_one_out, make_svm, svm_features
    from frontends.laser.recognition.recognizer import HeldOutParams, Recognizer, held_out_views
    from frontends.laser.recognition.views import ViewParams, builtin_models, load_database

    models = builtin_models()
    if not models:
        sys.exit("the simulator's CAD library (semslam.models.cad) is not available")
    params = ViewParams(n_views=args.views)
    t0 = time.perf_counter()
    db = load_database(models, params, cache_dir=args.cache_dir, include_user_models=False)
    print(f"view database: {len(db.labels)} views of {len(db.models)} models ({time.perf_counter() - t0:.1f} s)")
    held = HeldOutParams(n_per_model=args.held_out)
    clouds, labels = held_out_views(models, held, params.angular_resolution_rad)
    print(f"held-out views: {len(clouds)}")

    rows = []
    y = db.labels
    ext = db.features("extent")
    for desc in ("esf", "vfh", "cvfh"):
        X = db.features(desc)
        for size in (0.0, 0.2):
            loo = {}
            if desc != "cvfh":
                if size == 0.0:
                    loo["nn"] = float(np.mean(leave_one_out(ChiSquareNN, X, y) == y))
                feats = svm_features(X, ext if size else None)
                loo["svm"] = float(np.mean(leave_one_out(lambda: make_svm(n_size=3 if size else 0), feats, y) == y))  # noqa: B023
            for method in ("nn", "svm"):
                if desc == "cvfh" and method == "svm":
                    continue
                rec = Recognizer(db, descriptor=desc, method=method, size_weight=size, esf_samples=args.esf_samples)
                conf = rec.evaluate(clouds, labels)
                acc = float(np.trace(conf) / conf.sum())
                rows.append({"descriptor": desc, "method": method, "size_cue": size > 0,
                             "held_out_accuracy": acc, "loo_accuracy": loo.get(method), "confusion": conf.tolist()})  # fmt: skip
                print(f"{desc:5s} {method:3s} size cue {'on ' if size else 'off'}  held-out top-1 {acc:.3f}"
                      + (f"   LOO {loo[method]:.3f}" if loo.get(method) is not None else ""))  # fmt: skip

    best = next(r for r in rows if r["descriptor"] == "esf" and r["method"] == "nn" and r["size_cue"])
    syn = classification_metrics(np.array(best["confusion"]), db.classes)
    # Issue 7's acceptance: ESF top-1 ≥ 0.90 on held-out views (Himri et al.: 0.9375 with ESF + SVM).
    acc = {
        f"esf_{r['method']}{'_size' if r['size_cue'] else ''}": r["held_out_accuracy"]
        for r in rows
        if r["descriptor"] == "esf"
    }
    print(
        f"\nESF held-out top-1 (target ≥ 0.90; {args.esf_samples} query triplets): ESF alone NN {acc['esf_nn']:.3f}, "
        f"ESF alone SVM {acc['esf_svm']:.3f}, ESF + size NN {acc['esf_nn_size']:.3f} (the front-end's default), "
        f"ESF + size SVM {acc['esf_svm_size']:.3f}"
    )
    out = {"classes": db.classes, "confusion": best["confusion"], "recogniser": "esf + size cue, chi-square NN",
           "views_per_model": args.views, "held_out_per_model": args.held_out, "esf_samples": args.esf_samples,
           "esf_held_out_accuracy": acc, "all": rows}  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "syn_confusion.json").write_text(json.dumps(out, indent=1))
    print("\nSYN (ESF + size cue, chi-square NN):")
    print(format_table({"SYN": syn}))
    return out


def synthetic_records(syn: dict, n_landmarks: int, seed: int) -> list[ObservationRecord]:
    """Landmarks of every class seen 3–10 times by a recogniser whose errors follow ``syn``, with
    the pipe configuration of their class seen in half of the scans."""
    from semslam.semantics.likelihood import ConfusionModel

    classes = syn["classes"]
    counts = np.array(syn["confusion"], dtype=np.float64)
    model = ConfusionModel(counts, classes)  # the smoothed P(Z | X) the recogniser reports
    rates = counts / counts.sum(axis=1, keepdims=True)  # the errors it actually makes
    ports = {"Ball-Valve": [1, 2], "Butterfly-Valve": [1, 2], "R-Socket": [1, 2], "Elbow": [1, 3]}
    rng = np.random.default_rng(seed)
    events = []
    for lid in range(n_landmarks):
        cls = classes[lid % len(classes)]
        row = rates[classes.index(cls)]
        for t in range(int(rng.integers(3, 11))):
            z = classes[rng.choice(len(classes), p=row)]
            conf = int(rng.choice(ports.get(cls, [1, 2, 3, 4]))) if rng.random() < 0.5 else None
            events.append((t + rng.random(), ObservationRecord(cls, model.likelihood(z), lid, conf)))
    events.sort(key=lambda e: e[0])
    return [r for _, r in events]


def tank_records(args) -> tuple[list[ObservationRecord], dict]:
    """Observation records of the simulated tank mission with oracle segmentation and ids."""
    from frontends.laser.recognition.config import RecognitionConfig, recognizer_from_config
    from semslam.semantics.connectivity import configuration_of
    from semslam.sim import sensors as S
    from semslam.sim.config import TankSimConfig
    from semslam.sim.tank import OBJECT, PIPE, TankScene, make_layout
    from semslam.sim.trajectory import Trajectory

    cfg = TankSimConfig(seed=args.seed)
    layout = make_layout(cfg.structure, cfg.tank, cfg.seed)
    scene = TankScene(cfg.tank, layout)
    lo, hi = layout.bounds()
    traj = Trajectory(cfg.trajectory, np.array([*cfg.structure.center_xy_m, (lo[2] + hi[2]) / 2]))
    _, t = S.sample_times(0, cfg.laser.rate_hz, cfg.trajectory.duration_s, first=1)
    if args.max_scans:
        t = t[:: max(1, len(t) // args.max_scans)]
    # The recogniser as the laser front-end configures it (its ESF sample count included).
    rec = recognizer_from_config(RecognitionConfig(cache_dir=args.cache_dir, esf_samples=args.esf_samples))
    syn = {"classes": rec.classes, "confusion": rec.confusion.tolist()}
    T_BS = cfg.laser.mount.matrix()
    d_S = S.laser_ray_dirs(cfg.laser)
    objects = {o.id: o for o in layout.objects}
    pipes = {p.id: p for p in layout.pipes}
    rng = np.random.default_rng(args.seed + 1)
    records = []
    t0 = time.perf_counter()
    for i, T_WB in enumerate(traj.poses(t)):
        T_WS = T_WB @ T_BS
        dist, kind, ident = scene.cast(T_WS[:3, 3], d_S @ T_WS[:3, :3].T)
        r = dist + rng.normal(0.0, cfg.laser.range_sigma_m, size=len(dist))
        keep = np.isfinite(dist) & (r >= cfg.laser.min_range_m) & (r <= cfg.laser.max_range_m)
        pts = d_S * r[:, None]
        pipe_hits = np.bincount(ident[keep & (kind == PIPE)], minlength=len(pipes) + 1)
        for oid in np.unique(ident[keep & (kind == OBJECT)]):
            sel = keep & (kind == OBJECT) & (ident == oid)
            if sel.sum() < args.min_points:
                continue
            o = objects[int(oid)]
            dirs = []
            for pid in o.pipes:
                if pid < len(pipe_hits) and pipe_hits[pid] >= args.min_points:
                    p = pipes[pid]
                    far = p.q if np.linalg.norm(p.q - o.position) > np.linalg.norm(p.p - o.position) else p.p
                    dirs.append(far - o.position)
            records.append(ObservationRecord(o.cls, rec.classify(pts[sel], None), int(oid), configuration_of(dirs)))
        if (i + 1) % 25 == 0:
            print(f"  scan {i + 1}/{len(t)}: {len(records)} object observations ({time.perf_counter() - t0:.0f} s)")
    return records, syn


def main() -> None:
    ap = argparse.ArgumentParser(description="Recognition tables: SYN, DESC, BAYS, SEM.")
    ap.add_argument("--syn", action="store_true", help="compute the SYN stage from the CAD library")
    ap.add_argument("--records", type=Path, help="JSON Lines of object observations (see the module doc)")
    ap.add_argument("--synthetic", type=int, default=0, help="simulate this many landmarks instead of --records")
    ap.add_argument("--syn-confusion", type=Path, help="syn_confusion.json from an earlier --syn run")
    ap.add_argument("--tank", action="store_true", help="the simulated tank with oracle segmentation and ids")
    ap.add_argument("--max-scans", type=int, default=0, help="--tank: use about this many scans (0: all)")
    ap.add_argument("--min-points", type=int, default=50, help="--tank: fewest hits of a visible object or pipe")
    ap.add_argument(
        "--mode",
        choices=["online", "final"],
        default="online",
        help="score each observation online or with the final map",
    )
    ap.add_argument(
        "--views", type=int, default=24, help="database viewing directions per model (each at every distance)"
    )
    ap.add_argument("--held-out", type=int, default=30, help="held-out views per model")
    ap.add_argument("--cache-dir", type=Path, default=None)
    ap.add_argument(
        "--esf-samples", type=int, default=None,
        help="ESF triplets of a query segment (default: the front-end's, frontends.laser.recognition.esf_samples)",
    )  # fmt: skip
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("runs/recognition"))
    args = ap.parse_args()
    if args.esf_samples is None:
        from frontends.laser.recognition.config import RecognitionConfig

        args.esf_samples = RecognitionConfig().esf_samples

    syn = syn_stage(args) if args.syn else None
    if args.syn_confusion:
        syn = json.loads(args.syn_confusion.read_text())
    if not (args.records or args.synthetic or args.tank):
        return
    if args.tank:
        records, tank_syn = tank_records(args)
        syn = syn or tank_syn
        args.out.mkdir(parents=True, exist_ok=True)
        with open(args.out / "tank_records.jsonl", "w") as f:
            for r in records:
                f.write(json.dumps({"true_class": r.true_class, "likelihood": r.likelihood,
                                    "landmark_id": r.landmark_id, "configuration": r.configuration}) + "\n")  # fmt: skip
    elif syn is None:
        sys.exit("the DESC/BAYS/SEM stages need the SYN confusion: pass --syn or --syn-confusion FILE")
    else:
        records = read_records(args.records) if args.records else synthetic_records(syn, args.synthetic, args.seed)
    classes = syn["classes"]
    metrics = recognition_metrics(records, classes, syn_confusion=np.array(syn["confusion"]), mode=args.mode)
    print(f"\n{len(records)} observations of {len({r.landmark_id for r in records})} landmarks ({args.mode} scoring)\n")
    print(format_table(metrics))
    f1 = [metrics[s]["f1"] for s in ("DESC", "BAYS", "SEM")]
    print(f"\nDESC ≤ BAYS ≤ SEM (F1): {f1[0] <= f1[1] <= f1[2]};  SEM average F1 ≥ 0.90: {f1[2] >= 0.90}")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "recognition.json").write_text(json.dumps(metrics, indent=1))


if __name__ == "__main__":
    main()
