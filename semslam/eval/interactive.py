"""The report's interactive 3-D view (plotly): trajectories and maps of the truth and each estimator.

Each estimator is a legend group (a click on any of its entries hides or shows all of it); a
landmark's hover gives its id, class posterior and error against the ground truth. Axes are east,
north and up (−depth), so the view stands the right way up.

plotly.js (~4.8 MB) is embedded gzip-compressed (~2 MB as base64) and unpacked by the browser's
DecompressionStream (Chrome 80, Firefox 113, Safari 16.4 and later): the report works offline.
"""

from __future__ import annotations

import base64
import functools
import gzip
import json
import math

import numpy as np

from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.eval.metrics import match_landmarks
from semslam.eval.replay_scene import class_rgb, map_class
from semslam.mission.ground_truth import GroundTruthMap
from semslam.results import OBSERVATION_MAPS, PipelineResult

TRAJECTORY_POINTS = 2000  # at most this many points of each trajectory
MAP_POINTS = 500  # at most this many objects (and pipes) of one map: the DR map places every observation
COLORS = {"truth": "#000000", "dr": "#d62728", "ekf": "#1f77b4", "graph": "#2ca02c"}
SYMBOLS = {"truth": "diamond-open", "dr": "x", "ekf": "square", "graph": "circle"}
DIV_ID = "semslam-3d"


def _enu(points) -> np.ndarray:
    """NED (N, 3) → (east, north, up) for display."""
    p = np.asarray(points, float).reshape(-1, 3)
    return np.column_stack([p[:, 1], p[:, 0], -p[:, 2]])


def _rgb(rgb) -> str:
    return "rgb({:.0f},{:.0f},{:.0f})".format(*(255 * np.asarray(rgb)))


def _thin(n: int, at_most: int) -> np.ndarray:
    return np.arange(n) if n <= at_most else np.unique(np.linspace(0, n - 1, at_most).round().astype(int))


def _trace(group: str, label: str, points_ned, mode: str, **style) -> dict:
    """One scatter3d trace of a legend group (the truth or an estimator), shown east-north-up."""
    xyz = _enu(points_ned)
    return dict(
        type="scatter3d",
        mode=mode,
        x=xyz[:, 0],
        y=xyz[:, 1],
        z=xyz[:, 2],
        name=f"{group} {label}",
        legendgroup=group,
        legendgrouptitle=dict(text=group),
        **style,
    )


def _trajectory_trace(name: str, traj: Trajectory) -> dict:
    truth = name == "truth"
    line = dict(color=COLORS.get(name, "#7f7f7f"), width=4 if truth else 3, dash="dash" if truth else "solid")
    return _trace(
        name, "trajectory", traj.positions[_thin(len(traj), TRAJECTORY_POINTS)], "lines", line=line, hoverinfo="name"
    )


def _posterior_text(posterior) -> str:
    if not posterior:
        return "class: unknown"
    top = sorted(posterior.items(), key=lambda kv: -kv[1])[:3]
    return "class: " + ", ".join(f"{c} {p:.2f}" for c, p in top)


def _pipes_trace(name: str, segments: list[tuple[np.ndarray, np.ndarray, str]], color: str, width: int) -> dict:
    """Pipes as one line trace: segments separated by gaps, each end hovering its text."""
    ned, text = [], []
    for p, q, t in segments:
        ned += [p, q, [np.nan] * 3]
        text += [t, t, ""]
    style = dict(line=dict(color=color, width=width), text=text, hovertemplate="%{text}<extra></extra>")
    return _trace(name, "pipes", np.array(ned, float), "lines", **style)


def _points_trace(name: str, label: str, xyz: np.ndarray, colors: list[str], text: list[str]) -> dict:
    size = 3 if name in OBSERVATION_MAPS else 6
    marker = dict(color=colors, size=size, symbol=SYMBOLS.get(name, "circle"), line=dict(width=1))
    return _trace(name, label, xyz, "markers", marker=marker, text=text, hovertemplate="%{text}<extra></extra>")


def _map_traces(name: str, landmarks: list[LandmarkEstimate], truth: GroundTruthMap | None) -> list[dict]:
    """Objects (coloured by class), pipes and structures of one map; a map of placed observations
    (dead reckoning) starts hidden, as it would cover the others."""
    errors = {}
    if truth is not None and landmarks:
        errors = {m.estimate_id: (m.truth_id, m.error_m) for m in match_landmarks(landmarks, truth)[0]}

    def err(lm) -> str:
        if lm.id not in errors:
            return "error: no true landmark within 0.5 m" if truth is not None else "error: no ground truth"
        tid, e = errors[lm.id]
        return f"error {e:.3f} m (truth {tid})"

    traces = []
    objects = [lm for lm in landmarks if lm.kind == "object" and lm.position is not None]
    pick = _thin(len(objects), MAP_POINTS)
    if len(pick):
        shown = [objects[i] for i in pick]
        more = f" ({len(shown)} of {len(objects)})" if len(shown) < len(objects) else ""
        traces.append(
            _points_trace(
                name,
                "objects" + more,
                np.array([lm.position for lm in shown]),
                [_rgb(class_rgb(map_class(lm.class_posterior)[0])) for lm in shown],
                [f"{name} object {lm.id}<br>{_posterior_text(lm.class_posterior)}<br>{err(lm)}" for lm in shown],
            )
        )
    pipes = [lm for lm in landmarks if lm.kind == "pipe" and lm.p is not None]
    pick = _thin(len(pipes), MAP_POINTS)
    if len(pick):
        segs = [(pipes[i].p, pipes[i].q, f"{name} pipe {pipes[i].id}<br>{err(pipes[i])}") for i in pick]
        traces.append(_pipes_trace(name, segs, COLORS.get(name, "#7f7f7f"), 5))
    structures = [lm for lm in landmarks if lm.kind == "structure" and lm.pose is not None]
    if structures:
        traces.append(
            _points_trace(
                name,
                "structures",
                np.array([np.asarray(lm.pose)[:3, 3] for lm in structures]),
                [COLORS.get(name, "#7f7f7f")] * len(structures),
                [f"{name} structure {lm.id} ({lm.model})<br>{err(lm)}" for lm in structures],
            )
        )
    if name in OBSERVATION_MAPS:
        for t in traces:
            t["visible"] = "legendonly"
            t["name"] = t["name"].replace(f"{name} ", f"{name} observed ", 1)
    return traces


def _truth_traces(truth: GroundTruthMap) -> list[dict]:
    traces = []
    if truth.objects:
        traces.append(
            _points_trace(
                "truth",
                "objects",
                truth.object_positions(),
                [_rgb(class_rgb(o.cls)) for o in truth.objects],
                [f"truth object {o.id}<br>class: {o.cls}" for o in truth.objects],
            )
        )
    if truth.pipes:
        segs = [(np.array(p.p), np.array(p.q), f"truth pipe {p.id} (radius {p.radius:.3f} m)") for p in truth.pipes]
        traces.append(_pipes_trace("truth", segs, "#bbbbbb", 10))
    if truth.structures:
        traces.append(
            _points_trace(
                "truth",
                "structures",
                np.array([s.position for s in truth.structures]),
                ["#000000"] * len(truth.structures),
                [f"truth structure {s.id} ({s.model})" for s in truth.structures],
            )
        )
    return traces


def figure(pipeline: PipelineResult, truth: GroundTruthMap | None) -> dict:
    """The plotly figure (as a dict) of the truth and every estimator."""
    data = []
    if pipeline.truth is not None and len(pipeline.truth):
        data.append(_trajectory_trace("truth", pipeline.truth))
    if truth is not None:
        data += _truth_traces(truth)
    for name, result in pipeline.results.items():
        data += _estimator_traces(name, result, truth)
    layout = dict(
        height=720,
        margin=dict(l=0, r=0, t=40, b=0),
        legend=dict(groupclick="toggleitem", itemsizing="constant"),
        scene=dict(
            aspectmode="data",
            xaxis=dict(title=dict(text="east [m]")),
            yaxis=dict(title=dict(text="north [m]")),
            zaxis=dict(title=dict(text="up [m] (−depth)")),
        ),
        updatemenus=[_toggles(data)],
        annotations=[
            dict(text="show / hide:", showarrow=False, x=0, y=1.06, xref="paper", yref="paper", xanchor="left")
        ],
    )
    return dict(data=data, layout=layout)


def _toggles(data: list[dict]) -> dict:
    """One toggle button per legend group (the truth, each estimator): all its traces on, then off."""
    groups: dict[str, list[int]] = {}
    for i, t in enumerate(data):
        groups.setdefault(t["legendgroup"], []).append(i)
    buttons = [
        dict(
            label=g,
            method="restyle",
            args=[{"visible": True}, idx],
            args2=[{"visible": "legendonly"}, idx],
        )
        for g, idx in groups.items()
    ]
    return dict(type="buttons", direction="right", showactive=False, x=0.09, y=1.09, xanchor="left", buttons=buttons)


def _estimator_traces(name: str, result: EstimatorResult, truth: GroundTruthMap | None) -> list[dict]:
    traces = [_trajectory_trace(name, result.trajectory)] if len(result.trajectory) else []
    return traces + _map_traces(name, result.landmarks, truth)


def _json_default(x):
    if isinstance(x, np.ndarray):  # coordinates to 0.1 mm; NaN (a gap between pipes) as null
        if x.dtype.kind == "f":
            return [round(v, 4) if math.isfinite(v) else None for v in x.ravel().tolist()]  # Python floats: ~3× faster
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    raise TypeError(f"not JSON serialisable: {type(x)}")


@functools.cache
def _plotly_js_gzip_b64() -> str:
    from plotly.offline import get_plotlyjs

    return base64.b64encode(gzip.compress(get_plotlyjs().encode(), compresslevel=9, mtime=0)).decode()


def interactive_html(pipeline: PipelineResult, truth: GroundTruthMap | None) -> str:
    """The 3-D view as an HTML fragment: its div, plotly.js (embedded) and the figure."""
    fig = json.dumps(figure(pipeline, truth), default=_json_default, separators=(",", ":"))
    fig = fig.replace("<", "\\u003c")  # hover texts hold <br>: no "</script>" or "<!--" inside the script element
    return f"""<div id="{DIV_ID}" style="width:100%;height:720px">
<p class="loading">Loading the 3-D view&hellip; (it needs JavaScript and a browser with DecompressionStream:
Chrome 80, Firefox 113, Safari 16.4 or later)</p></div>
<script id="{DIV_ID}-plotly" type="application/octet-stream">{_plotly_js_gzip_b64()}</script>
<script id="{DIV_ID}-figure" type="application/json">{fig}</script>
<script>
(async () => {{
  const div = document.getElementById("{DIV_ID}");
  try {{
    const b64 = document.getElementById("{DIV_ID}-plotly").textContent;
    const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    const js = await new Response(new Blob([bytes]).stream().pipeThrough(new DecompressionStream("gzip"))).text();
    const s = document.createElement("script");
    s.textContent = js;
    document.head.appendChild(s);
    const fig = JSON.parse(document.getElementById("{DIV_ID}-figure").textContent);
    div.innerHTML = "";
    await Plotly.newPlot(div, fig.data, fig.layout, {{responsive: true, displaylogo: false}});
    div.dataset.rendered = "yes";
  }} catch (e) {{
    div.textContent = "The 3-D view could not be drawn: " + e;
  }}
}})();
</script>"""
