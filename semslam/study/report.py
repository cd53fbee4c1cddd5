"""``DIR/report.html``: a self-contained page (figures embedded) that opens with the distributions
and the paired ratios' confidence intervals, then the worst missions (linked to their own
reports), every mission, and the failures."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np

from semslam.study.stats import CONFIDENCE
from semslam.study.store import write_atomic

#: (metric, label) shown as distributions, in this order
FIGURE_METRICS = (
    ("ate_rmse_m", "ATE RMSE (m)"),
    ("ate_rmse_se3_m", "ATE RMSE after SE(3) alignment (m)"),
    ("rpe_rmse_m", "RPE RMSE (m)"),
    ("landmark_median_error_m", "landmark median error (m)"),
    ("nees_mean", "mean position NEES"),
    ("objects_mapped_ratio", "objects mapped / seen"),
    ("pipes_mapped_ratio", "pipes mapped / seen"),
    ("runtime_s", "estimator run time (s)"),
    ("gps_error_rmse_m", "error at the held-out GPS fixes (m)"),
)
#: further rows of the distributions table (map quality, consistency), shown where a mission has them
TABLE_METRICS = (
    ("ate_rmse_pos_yaw_m", "ATE RMSE after position+yaw alignment (m)"),
    ("object_median_error_m", "object median error (m)"),
    ("pipe_median_error_m", "pipe median error (m)"),
    ("object_duplicates", "objects mapped twice"),
    ("object_missed", "objects missed"),
    ("object_false", "false objects"),
    ("pipes_seen_mapped_ratio", "pipes mapped / seen by the front-end"),
    ("pipe_duplicate_ratio", "pipe duplicates / pipes"),
    ("pipe_false", "false pipes"),
    ("structure_missed", "structures missed"),
    ("structure_false", "false structures"),
    ("recovered_failures", "solver failures recovered from"),
    ("nees_share_in_pose_band", "poses with NEES in the 95 % band"),
    ("gps_error_last_m", "error at the last held-out GPS fix (m)"),
)
#: yes/no per mission (study.json's ``shares``)
SHARE_LABELS = {
    "objects_once": "every object mapped exactly once",
    "nees_in_band": "mean position NEES in the 95 % χ² band",
}
LABELS = {
    **dict(FIGURE_METRICS),
    **dict(TABLE_METRICS),
}


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _fmt(v, digits: int = 3) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}" if abs(v) < 1e4 else f"{v:.0f}"
    return str(v)


def _ci(ci) -> str:
    return "–" if ci is None else f"[{_fmt(ci[0])}, {_fmt(ci[1])}]"


def _table(header: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def distributions_figure(study: dict) -> str | None:
    """Box plots with every mission as a dot, one panel per metric, one box per estimator (and the
    recognition F1 per stage): base64 PNG, or None when no mission finished."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dists = study["distributions"]
    panels = [(k, label, {e: d[k]["values"] for e, d in dists.items()}) for k, label in FIGURE_METRICS]
    if study["recognition"]:
        panels.append(("f1", "recognition F1", {st: d["f1"]["values"] for st, d in study["recognition"].items()}))
    panels = [(k, lab, {n: [v for v in vals if v is not None] for n, vals in g.items()}) for k, lab, g in panels]
    panels = [p for p in panels if any(p[2].values())]
    if not panels:
        return None
    cols = 3
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    rng = np.random.default_rng(0)
    for ax, (_, label, groups) in zip(axes.flat, panels):
        names = list(groups)
        data = [groups[n] or [np.nan] for n in names]
        ax.boxplot(data, showfliers=False)
        for i, vals in enumerate(data, start=1):
            ax.plot(i + rng.uniform(-0.12, 0.12, len(vals)), vals, ".", alpha=0.6, color="tab:blue")
        ax.set_xticks(range(1, len(names) + 1), names, rotation=20)
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(panels) :]:
        ax.axis("off")
    fig.tight_layout()
    return _png(fig)


def ratios_figure(study: dict) -> str | None:
    """Per-mission paired ratios (log scale) with their median and its confidence interval."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    items = [
        (f"{pair} {LABELS.get(k, k).split(' (')[0]}", r)
        for pair, block in study["ratios"].items()
        for k, r in block.items()
        if r["n"]
    ]
    if not items:
        return None
    fig, ax = plt.subplots(figsize=(9, 0.45 * len(items) + 1.2))
    rng = np.random.default_rng(0)
    for y, (_, r) in enumerate(items):
        vals = [v for v in r["values"] if v is not None]
        ax.plot(vals, y + rng.uniform(-0.15, 0.15, len(vals)), ".", alpha=0.5, color="tab:blue")
        if r["median_ci95"]:
            lo, hi = r["median_ci95"]
            ax.plot([lo, hi], [y, y], "-", color="k", lw=2)
        ax.plot([r["median"]], [y], "D", color="tab:red")
    ax.axvline(1.0, color="grey", ls="--")
    ax.set_xscale("log")
    ax.set_yticks(range(len(items)), [name for name, _ in items])
    ax.set_xlabel(f"per-mission ratio (red: median, black: its {int(CONFIDENCE * 100)} % bootstrap CI)")
    ax.invert_yaxis()
    ax.grid(alpha=0.3, axis="x")
    fig.tight_layout()
    return _png(fig)


def _link(target: str | None, text: str) -> str:
    return html.escape(text) if not target else f"<a href='{html.escape(target)}'>{html.escape(text)}</a>"


def write_study_report(out_dir: Path, study: dict) -> Path:
    c = study["counts"]
    parts = [
        f"<h1>semslam study — {html.escape(study['study'].get('title', str(out_dir)))}</h1>",
        f"<p>{c['ok']} of {c['planned']} missions finished; {c['failed']} failed, {c['timeout']} timed out, "
        f"{c['not_run']} not run. Per-mission numbers: <code>study.json</code>.</p>",
        "<h2>Paired ratios</h2>",
        "<p>Per mission, the first estimator's error over the second's (&lt; 1: the first is better); "
        f"{int(CONFIDENCE * 100)} % bootstrap confidence intervals (BCa) over the missions.</p>",
    ]
    rows = [
        [
            html.escape(pair),
            html.escape(LABELS.get(k, k)),
            str(r["n"]),
            _fmt(r["median"]),
            _ci(r["median_ci95"]),
            _fmt(r["geomean"]),
            _ci(r["geomean_ci95"]),
            _fmt(r["share_below_1"]),
        ]
        for pair, block in study["ratios"].items()
        for k, r in block.items()
        if r["n"]  # a metric no mission of the pair has (no landmarks, no held-out fix)
    ]
    parts.append(_table(["pair", "metric", "n", "median", "95 % CI", "geo. mean", "95 % CI", "share < 1"], rows))
    fig = ratios_figure(study)
    if fig:
        parts.append(f"<img alt='paired ratios' src='data:image/png;base64,{fig}'>")
    parts.append("<h2>Distributions</h2>")
    fig = distributions_figure(study)
    if fig:
        parts.append(f"<img alt='distributions' src='data:image/png;base64,{fig}'>")
    rows = []
    for est, d in study["distributions"].items():
        for k, label in (*FIGURE_METRICS, *TABLE_METRICS):
            s = d.get(k)
            if not s or not s["n"]:
                continue
            rows.append([html.escape(est), html.escape(label), str(s["n"]), _fmt(s["median"])])
            rows[-1] += [
                f"{_fmt(s['p25'])} – {_fmt(s['p75'])}",
                f"{_fmt(s['min'])} – {_fmt(s['max'])}",
                _fmt(s["mean"]),
            ]
    for st, d in study["recognition"].items():
        s = d["f1"]
        rows.append(["recognition " + html.escape(st), "F1", str(s["n"]), _fmt(s["median"])])
        rows[-1] += [f"{_fmt(s['p25'])} – {_fmt(s['p75'])}", f"{_fmt(s['min'])} – {_fmt(s['max'])}", _fmt(s["mean"])]
    parts.append(_table(["estimator", "metric", "n", "median", "p25 – p75", "min – max", "mean"], rows))
    rows = [
        [html.escape(est), html.escape(SHARE_LABELS.get(k, k)), str(v["n"]), _fmt(v["share"])]
        for est, block in study.get("shares", {}).items()
        for k, v in block.items()
        if v["n"]
    ]
    if rows:
        parts.append("<h2>Share of missions</h2>")
        parts.append(_table(["estimator", "", "n", "share"], rows))
    if study["worst"]:
        parts.append("<h2>Worst missions</h2>")
        rows = [
            [_link(w["report"], w["mission"]), html.escape(w["estimator"]), _fmt(w["ate_rmse_m"])]
            for w in study["worst"]
        ]
        parts.append(_table(["mission", "estimator", "ATE RMSE (m)"], rows))
    parts.append("<h2>Missions</h2>")
    rows = []
    for m in study["missions"]:
        ests = (m["summary"] or {}).get("estimators", {})
        ate = " / ".join(_fmt((ests.get(e) or {}).get("ate_rmse_m")) for e in ("dr", "ekf", "graph"))
        rows.append(
            [
                _link(m["report"], m["mission"]),
                html.escape(m["status"]),
                ate,
                _fmt(m["wall_s"], 4),
                html.escape(m["error"] or ""),
            ]
        )
    parts.append(_table(["mission", "status", "ATE dr / ekf / graph (m)", "wall (s)", "error"], rows))
    if study["failures"]:
        parts.append("<h2>Failures</h2>")
        rows = [
            [
                html.escape(f["mission"]),
                html.escape(f["status"]),
                html.escape(f["error"] or ""),
                _link(f.get("log"), "log"),
            ]
            for f in study["failures"]
        ]
        parts.append(_table(["mission", "status", "error", "log"], rows))
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>semslam study</title>
<style>body{{font-family:sans-serif;max-width:1300px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}
td:first-child,th:first-child,td:nth-child(2){{text-align:left}}img{{max-width:100%}}</style></head>
<body>{"".join(parts)}</body></html>"""
    write_atomic(out_dir / "report.html", page)
    return out_dir / "report.html"
