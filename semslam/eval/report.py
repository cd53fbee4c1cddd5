"""The comparison report: figures/*.png, report.md and a self-contained report.html."""

from __future__ import annotations

import base64
import html
from pathlib import Path

import matplotlib.pyplot as plt

from semslam.collector import heap_frozen
from semslam.eval import figures
from semslam.mission.mission import MissionMetadata
from semslam.results import PipelineResult

ROWS = [
    ("ATE RMSE [m]", "ate_rmse_m", "{:.3f}"),
    ("ATE RMSE, SE(3)-aligned [m]", "ate_rmse_se3_m", "{:.4f}"),
    ("ATE max [m]", "ate_max_m", "{:.3f}"),
    ("RPE RMSE [m/m]", "rpe_rmse_m", "{:.3f}"),
    ("landmark median error [m]", "landmark_median_error_m", "{:.3f}"),
    ("objects mapped", "n_objects", "{}"),
    ("pipes mapped", "n_pipes", "{}"),
    ("structures mapped", "n_structures", "{}"),
    ("duplicated landmarks", "landmark_duplicates", "{}"),
    ("NEES (position, mean; 3 = consistent)", "nees_mean", "{:.2f}"),
    ("update median [ms]", "update_ms_median", "{:.2f}"),
    ("update p95 [ms]", "update_ms_p95", "{:.2f}"),
    ("run time [s]", "runtime_s", "{:.1f}"),
]


FRONTEND_FIGURE_CAPTIONS = {
    "sonar_elevation": "Sonar: elevation map with the recognised structures and pipelines",
    "sonar_world_model": "Sonar: world model (registered CAD structures and seabed surface)",
}


def timing_table(metrics: dict) -> list[list[str]]:
    """Where the time went: reading, each front-end, each estimator, and the real-time factor."""
    timing = metrics.get("timing_s") or {}
    if not timing:
        return []
    duration = (metrics.get("mission") or {}).get("duration_s") or 0.0
    rows = [["stage", "time [s]", "× real time"]]
    total = 0.0
    for key in sorted((k for k in timing if k != "wall"), key=lambda k: (k.split(":")[0] != "read", k)):
        t = float(timing[key])
        total += t
        rows.append([key.replace(":", " "), f"{t:.1f}", f"{duration / t:.0f}" if t > 0 and duration else "–"])
    rows.append(["sum of the stages", f"{total:.1f}", f"{duration / total:.1f}" if total > 0 and duration else "–"])
    if "wall" in timing:  # front-ends ran in their own process, beside the estimators
        wall = float(timing["wall"])
        rows.append(
            ["wall (front-ends in parallel)", f"{wall:.1f}", f"{duration / wall:.1f}" if wall > 0 and duration else "–"]
        )
    return rows


def sonar_table(metrics: dict) -> list[list[str]]:
    sonar = metrics.get("sonar") or {}
    rows = [["structure", "found", "median point-to-model [m]", "yaw error [°]", "position error [m]"]]
    for st in sonar.get("structures") or []:
        rows.append(
            [
                str(st.get("model")),
                _found(st),
                _fmt(st.get("median_error_m"), "{:.3f}"),
                _fmt(st.get("yaw_error_deg"), "{:.2f}"),
                _fmt(st.get("position_error_m"), "{:.3f}"),
            ]
        )
    return rows if len(rows) > 1 else []


def _found(st: dict) -> str:
    """yes / no (missed) for a true structure; a registration at no right place: wrong place or false."""
    if st.get("found"):
        return "yes"
    if st.get("truth_id") is not None:
        return "no"
    return "wrong place" if st.get("wrong_place") else "false"


def _fmt(value, fmt) -> str:
    return "–" if value is None else fmt.format(value)


def metrics_table(metrics: dict) -> list[list[str]]:
    """The estimator comparison as rows of strings (header first)."""
    names = list(metrics["estimators"])
    rows = [["", *names]]
    for label, key, fmt in ROWS:
        rows.append([label, *(_fmt(metrics["estimators"][n].get(key), fmt) for n in names)])
    return rows


def recognition_table(metrics: dict) -> list[list[str]]:
    rec = metrics.get("recognition") or {}
    rows = [["stage", "accuracy", "precision", "recall", "F1"]]
    for stage in ("SYN", "DESC", "BAYS", "SEM"):
        if stage in rec:
            r = rec[stage]
            rows.append([stage, *(_fmt(r.get(k), "{:.2f}") for k in ("accuracy", "precision", "recall", "f1"))])
    return rows if len(rows) > 1 else []


def text_table(rows: list[list[str]]) -> str:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))) for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _md_table(rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(rows[0])]
    out += ["| " + " | ".join(r) + " |" for r in rows[1:]]
    return "\n".join(out)


def _html_table(rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in rows[0])
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows[1:])
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def make_figures(
    out_dir: Path, pipeline: PipelineResult, metadata: MissionMetadata, metrics: dict
) -> list[tuple[str, Path]]:
    """Render every figure that the available data allows; returns (caption, path) pairs."""
    fig_dir = out_dir / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    gt = metadata.ground_truth
    results = pipeline.results
    classes = list(gt.classes) if gt is not None else []
    candidates = [
        (
            "Trajectories: truth, DR, EKF and graph (top and side views)",
            "trajectories.png",
            lambda: figures.trajectories(pipeline.truth, results),
        ),
        (
            "Maps: DR (every observation placed with the DR pose), EKF and graph over the true landmarks",
            "maps.png",
            lambda: figures.maps(results, gt),
        ),
        (
            "Position error with ±2σ over time",
            "position_error.png",
            lambda: figures.position_errors(pipeline.truth, results) if pipeline.truth is not None else None,
        ),
        ("Body velocity with ±2σ over time", "velocity.png", lambda: figures.velocities(results)),
        (
            "Uncertainty volume of each pipe and object over time",
            "uncertainty_volume.png",
            lambda: figures.uncertainty_volumes(
                results, pipeline.truth.stamps[0] if pipeline.truth is not None else None
            ),
        ),
        (
            "Recognition confusion matrices per stage",
            "confusion.png",
            lambda: figures.confusion_matrices(metrics.get("recognition") or {}, classes),
        ),
        ("Per-update time against the number of landmarks", "update_cost.png", lambda: figures.update_cost(results)),
    ]
    made = []
    known = {name for _, name, _ in candidates}
    for caption, name, build in candidates:
        fig = build()
        if fig is None:
            continue
        path = fig_dir / name
        fig.savefig(path, dpi=110, pil_kwargs={"compress_level": 1})  # ~10 % larger, encoded in ~2/3 of the time
        plt.close(fig)
        made.append((caption, path))
    # Figures the front-ends wrote themselves (e.g. the sonar elevation map and world model).
    for path in sorted(fig_dir.glob("*.png")):
        if path.name not in known:
            made.append((FRONTEND_FIGURE_CAPTIONS.get(path.stem, path.stem.replace("_", " ")), path))
    return made


REPLAY_NOTE = (
    "replay.mcap is the run as a ROS 2 bag: open it in Foxglove (Open local file, then import the layout "
    "foxglove_layout.json beside it) or play it with `ros2 bag play replay.mcap --clock` for RViz "
    "(fixed frame `map`; topics and frames: semslam's README)."
)


@heap_frozen()
def write_report(
    out_dir: str | Path, pipeline: PipelineResult, metadata: MissionMetadata, metrics: dict, replay: bool = False
) -> Path:
    """figures/*.png, report.md and a self-contained report.html (images and the interactive 3-D
    view embedded; it works offline). ``replay``: the directory holds replay.mcap (say how to open it)."""
    from semslam.eval.interactive import interactive_html

    out_dir = Path(out_dir)
    figs = make_figures(out_dir, pipeline, metadata, metrics)
    title = f"semslam comparison — {metadata.name}"
    est_rows = metrics_table(metrics)
    rec_rows = recognition_table(metrics)
    m = metrics["mission"]
    mission_line = (
        f"Mission duration {m['duration_s']:.0f} s; ground-truth landmarks seen: "
        f"{m['gt_objects']} objects, {m['gt_pipes']} pipes, {m['gt_structures']} structures."
    )
    time_rows = timing_table(metrics)
    sonar_rows = sonar_table(metrics)
    sonar = metrics.get("sonar") or {}
    sonar_line = ""
    if sonar_rows and sonar.get("world_model_bytes") and sonar.get("raw_cloud_bytes"):
        sonar_line = (
            f"World model {sonar['world_model_bytes'] / 1e3:.0f} kB for a raw cloud of "
            f"{sonar['raw_cloud_bytes'] / 1e6:.1f} MB ({100 * sonar['world_model_bytes'] / sonar['raw_cloud_bytes']:.2f} %)."
        )
    md = [f"# {title}", "", mission_line, "", *([REPLAY_NOTE, ""] if replay else [])]
    md += ["## Estimators", "", _md_table(est_rows), ""]
    if rec_rows:
        md += ["## Recognition", "", _md_table(rec_rows), ""]
    if sonar_rows:
        md += ["## Sonar structures", "", _md_table(sonar_rows), "", sonar_line, ""]
    if time_rows:
        md += ["## Run time", "", _md_table(time_rows), ""]
    md += ["The interactive 3-D view (trajectories and maps) is in report.html.", "", "## Figures", ""]
    md += [f"### {cap}\n\n![{cap}](figures/{p.name})\n" for cap, p in figs]
    (out_dir / "report.md").write_text("\n".join(md))

    imgs = "".join(
        f"<figure><img alt='{html.escape(cap)}' src='data:image/png;base64,"
        f"{base64.b64encode(p.read_bytes()).decode()}'><figcaption>{html.escape(cap)}</figcaption></figure>"
        for cap, p in figs
    )
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #ccc;padding:4px 10px;text-align:right}}
td:first-child,th:first-child{{text-align:left}}figure{{margin:2em 0}}img{{max-width:100%}}
figcaption{{color:#555;font-size:90%}}</style></head><body>
<h1>{html.escape(title)}</h1><p>{html.escape(mission_line)}</p>
{f"<p>{html.escape(REPLAY_NOTE)}</p>" if replay else ""}
<h2>Trajectories and maps in 3-D</h2>{interactive_html(pipeline, metadata.ground_truth)}
<h2>Estimators</h2>{_html_table(est_rows)}
{"<h2>Recognition</h2>" + _html_table(rec_rows) if rec_rows else ""}
{"<h2>Sonar structures</h2>" + _html_table(sonar_rows) + f"<p>{html.escape(sonar_line)}</p>" if sonar_rows else ""}
{"<h2>Run time</h2>" + _html_table(time_rows) if time_rows else ""}
<h2>Figures</h2>{imgs}</body></html>"""
    (out_dir / "report.html").write_text(page)
    return out_dir / "report.html"
