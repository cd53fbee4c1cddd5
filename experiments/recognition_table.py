"""The recognition tables of Vallicrosa et al. 2021 (Tables 3–4) and Himri et al. 2018.

Two parts, run separately or together:

``--syn``  The recogniser on synthetic views of the CAD library: the view database (cached), its
           leave-one-out accuracy (Himri et al.: chi-square NN and RBF SVM, per descriptor), and
           the SYN confusion matrix on held-out views (random viewpoints, distances 1–2.5 m and
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

Output: a Markdown table on stdout, and ``OUT/recognition.json`` in the ``metrics.json``
"recognition" layout ({stage: {accuracy, precision, recall, f1, confusion, per_class, ...}}).

    python experiments/recognition_table.py --syn --out runs/recognition
    python experiments/recognition_table.py --records obs.jsonl --syn-confusion runs/recognition/syn_confusion.json
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
        sys.exit("the simulator's CAD library (semslam.sim.cad) is not available")
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
                loo["svm"] = float(np.mean(leave_one_out(lambda: make_svm(n_size=3 if size else 0), feats, y) == y))
            for method in ("nn", "svm"):
                if desc == "cvfh" and method == "svm":
                    continue
                rec = Recognizer(db, descriptor=desc, method=method, size_weight=size)
                conf = rec.evaluate(clouds, labels)
                acc = float(np.trace(conf) / conf.sum())
                rows.append({"descriptor": desc, "method": method, "size_cue": size > 0,
                             "held_out_accuracy": acc, "loo_accuracy": loo.get(method), "confusion": conf.tolist()})  # fmt: skip
                print(f"{desc:5s} {method:3s} size cue {'on ' if size else 'off'}  held-out top-1 {acc:.3f}"
                      + (f"   LOO {loo[method]:.3f}" if loo.get(method) is not None else ""))  # fmt: skip

    best = next(r for r in rows if r["descriptor"] == "esf" and r["method"] == "nn" and r["size_cue"])
    syn = classification_metrics(np.array(best["confusion"]), db.classes)
    out = {"classes": db.classes, "confusion": best["confusion"], "recogniser": "esf + size cue, chi-square NN",
           "views_per_model": args.views, "held_out_per_model": args.held_out, "all": rows}  # fmt: skip
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


def main() -> None:
    ap = argparse.ArgumentParser(description="Recognition tables: SYN, DESC, BAYS, SEM.")
    ap.add_argument("--syn", action="store_true", help="compute the SYN stage from the CAD library")
    ap.add_argument("--records", type=Path, help="JSON Lines of object observations (see the module doc)")
    ap.add_argument("--synthetic", type=int, default=0, help="simulate this many landmarks instead of --records")
    ap.add_argument("--syn-confusion", type=Path, help="syn_confusion.json from an earlier --syn run")
    ap.add_argument("--mode", choices=["online", "final"], default="online", help="score each observation online or with the final map")
    ap.add_argument("--views", type=int, default=42, help="database views per model")
    ap.add_argument("--held-out", type=int, default=30, help="held-out views per model")
    ap.add_argument("--cache-dir", type=Path, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("runs/recognition"))
    args = ap.parse_args()

    syn = syn_stage(args) if args.syn else None
    if args.syn_confusion:
        syn = json.loads(args.syn_confusion.read_text())
    if not (args.records or args.synthetic):
        return
    if syn is None:
        sys.exit("the DESC/BAYS/SEM stages need the SYN confusion: pass --syn or --syn-confusion FILE")
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
