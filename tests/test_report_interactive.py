"""The report's interactive 3-D view: what it shows, what its hover says, and that it needs no network.
(That it renders in a real browser: experiments/report_screenshot.py.)"""

import base64
import gzip
import json
import re

import numpy as np

from semslam.estimation import EstimatorResult, LandmarkEstimate, Trajectory
from semslam.eval.interactive import figure, interactive_html
from semslam.mission import GroundTruthMap, GtObject, GtPipe, MissionMetadata
from semslam.results import PipelineResult

TRUTH = GroundTruthMap(
    classes=("Elbow", "R-Tee"),
    objects=(GtObject(7, "Elbow", (1.0, 2.0, 3.0)), GtObject(8, "R-Tee", (4.0, 2.0, 3.0))),
    pipes=(GtPipe(20, (0.0, 0.0, 3.0), (0.0, 5.0, 3.0), 0.03),),
)


def _traj(n=50, east=0.0):
    s = np.arange(n, dtype=np.int64) * 10**8
    pos = np.column_stack([0.1 * np.arange(n), np.full(n, east), np.full(n, 2.0)])
    return Trajectory(s, pos, np.tile([0.0, 0, 0, 1], (n, 1)))


def _pipeline():
    graph = [
        LandmarkEstimate(
            3, "object", position=np.array([1.0, 2.0, 3.02]), class_posterior={"Elbow": 0.8, "R-Tee": 0.2}
        ),
        LandmarkEstimate(4, "pipe", p=np.array([0.01, 1.0, 3.0]), q=np.array([0.01, 4.0, 3.0])),
        LandmarkEstimate(5, "object", position=np.array([9.0, 9.0, 9.0]), class_posterior={"R-Tee": 1.0}),
    ]
    dr = [LandmarkEstimate(i, "object", position=np.array([1.0, 2.0, 3.0 + 0.001 * i])) for i in range(1200)]
    results = {"dr": EstimatorResult("dr", _traj(east=0.3), dr), "graph": EstimatorResult("graph", _traj(), graph)}
    return PipelineResult(results, _traj(east=0.01))


def _by_name(fig):
    return {t["name"]: t for t in fig["data"]}


def test_trajectories_and_maps_of_the_truth_and_each_estimator():
    fig = figure(_pipeline(), TRUTH)
    traces = _by_name(fig)
    assert {
        "truth trajectory",
        "truth objects",
        "truth pipes",
        "graph trajectory",
        "graph objects",
        "graph pipes",
    } <= set(traces)
    # displayed east, north, up: a point north 1, east 2, depth 3 is at (2, 1, -3)
    obj = traces["graph objects"]
    assert (obj["x"][0], obj["y"][0], obj["z"][0]) == (2.0, 1.0, -3.02)
    assert obj["marker"]["color"][0] == "rgb(38,140,230)"  # Elbow's class colour
    assert fig["layout"]["scene"]["zaxis"]["title"]["text"].startswith("up")


def test_hover_gives_id_class_posterior_and_error():
    traces = _by_name(figure(_pipeline(), TRUTH))
    hover = traces["graph objects"]["text"]
    assert hover[0] == "graph object 3<br>class: Elbow 0.80, R-Tee 0.20<br>error 0.020 m (truth 7)"
    assert hover[1].endswith("error: no true landmark within 0.5 m")
    assert "graph pipe 4<br>error 0.010 m (truth 20)" in traces["graph pipes"]["text"]


def test_toggles_per_estimator_and_the_dr_map_starts_hidden():
    fig = figure(_pipeline(), TRUTH)
    (menu,) = fig["layout"]["updatemenus"]
    groups = {b["label"]: b for b in menu["buttons"]}
    assert list(groups) == ["truth", "dr", "graph"]
    for label, b in groups.items():
        members = [i for i, t in enumerate(fig["data"]) if t["legendgroup"] == label]
        assert b["args"] == [{"visible": True}, members] and b["args2"] == [{"visible": "legendonly"}, members]
    dr_map = [t for t in fig["data"] if t["legendgroup"] == "dr" and "trajectory" not in t["name"]]
    assert dr_map and all(t["visible"] == "legendonly" for t in dr_map)
    (objects,) = dr_map
    assert objects["name"] == "dr observed objects (500 of 1200)"  # thinned: the DR map is every observation


def test_embedded_plotly_and_figure_work_offline():
    from plotly.offline import get_plotlyjs

    page = interactive_html(_pipeline(), TRUTH)
    assert not re.search(r"<script[^>]+src=", page)  # nothing fetched
    packed = re.search(r'id="semslam-3d-plotly" type="application/octet-stream">([^<]*)</script>', page).group(1)
    assert gzip.decompress(base64.b64decode(packed)).decode() == get_plotlyjs()
    data = re.search(r'id="semslam-3d-figure" type="application/json">(.*?)</script>', page, re.S).group(1)
    assert "<" not in data  # no "</script>" can end the element early
    fig = json.loads(data)
    assert fig["data"][0]["name"] == "truth trajectory" and "<br>" in fig["data"][1]["text"][0]  # decoded back


def test_the_report_page_has_the_3d_view(tmp_path):
    from semslam.eval.outputs import build_metrics
    from semslam.eval.report import write_report

    pipeline, meta = _pipeline(), MissionMetadata(ground_truth=TRUTH)
    page = write_report(tmp_path, pipeline, meta, build_metrics(pipeline, meta), replay=True).read_text()
    assert page.count('<div id="semslam-3d"') == 1 and "replay.mcap" in page
    assert "replay.mcap" in (tmp_path / "report.md").read_text()
