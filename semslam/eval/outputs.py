"""The output directory of DESIGN.md: config, TUM trajectories, semantic maps (JSON + PLY), metrics.

Everything is written into a staging folder beside the target and moved in at the end, so a
failure leaves no half-written output behind.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from semslam.config import SemslamConfig, dump_config
from semslam.estimation import EstimatorResult, LandmarkEstimate
from semslam.eval.metrics import estimator_metrics, sonar_metrics
from semslam.eval.recognition import recognition_block
from semslam.mission.mission import MissionMetadata
from semslam.results import PipelineResult


def _tolist(x):
    return None if x is None else np.asarray(x, float).tolist()


def map_to_dict(result: EstimatorResult) -> dict:
    """The semantic map: objects (with class posterior and MAP class), pipes, structures, connectivity."""
    objects, pipes, structures = [], [], []
    for lm in result.landmarks:
        base = {"id": lm.id, "n_observations": lm.n_observations, "covariance": _tolist(lm.covariance)}
        if lm.kind == "object":
            post = dict(lm.class_posterior or {})
            objects.append(
                base
                | {
                    "position": _tolist(lm.position),
                    "class_posterior": post,
                    "class": max(post, key=post.get) if post else None,
                    "connected_pipes": list(lm.connected),
                }
            )
        elif lm.kind == "pipe":
            pipes.append(base | {"p": _tolist(lm.p), "q": _tolist(lm.q), "connected": list(lm.connected)})
        elif lm.kind == "structure":
            structures.append(base | {"model": lm.model, "pose": _tolist(lm.pose), "connected": list(lm.connected)})
    # Every link once (object ↔ pipe, pipe ↔ structure), as [smaller id, larger id].
    links = sorted({tuple(sorted((lm.id, c))) for lm in result.landmarks for c in lm.connected})
    return {
        "estimator": result.name,
        "objects": objects,
        "pipes": pipes,
        "structures": structures,
        "connectivity": [list(pair) for pair in links],
    }


def map_geometry(landmarks: list[LandmarkEstimate]):
    """The map as one open3d triangle mesh: spheres for objects, cylinders for pipes, frames for structures."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh()
    for lm in landmarks:
        if lm.kind == "object" and lm.position is not None:
            s = o3d.geometry.TriangleMesh.create_sphere(radius=0.05, resolution=8)
            s.translate(lm.position)
            s.paint_uniform_color([0.9, 0.4, 0.1])
            mesh += s
        elif lm.kind == "pipe" and lm.p is not None:
            axis = np.asarray(lm.q) - np.asarray(lm.p)
            length = float(np.linalg.norm(axis))
            if length < 1e-6:
                continue
            c = o3d.geometry.TriangleMesh.create_cylinder(radius=0.03, height=length, resolution=12)
            z = axis / length
            # rotation taking +z to the pipe axis
            v = np.cross([0, 0, 1], z)
            s_, c_ = np.linalg.norm(v), z[2]
            if s_ < 1e-9:
                R = np.eye(3) if c_ > 0 else np.diag([1, -1, -1])
            else:
                vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
                R = np.eye(3) + vx + vx @ vx * ((1 - c_) / s_**2)
            c.rotate(R, center=(0, 0, 0))
            c.translate((np.asarray(lm.p) + np.asarray(lm.q)) / 2)
            c.paint_uniform_color([0.2, 0.5, 0.9])
            mesh += c
        elif lm.kind == "structure" and lm.pose is not None:
            f = o3d.geometry.TriangleMesh.create_coordinate_frame(size=0.5)
            f.transform(np.asarray(lm.pose))
            mesh += f
    return mesh


def _has_distinct_online(result: EstimatorResult) -> bool:
    """A smoother's online estimate differs from its final one; a filter's is the same thing."""
    on, tr = result.online_trajectory, result.trajectory
    if on is None or on is tr:
        return False
    return not (len(on) == len(tr) and np.array_equal(on.positions, tr.positions))


def build_metrics(pipeline: PipelineResult, metadata: MissionMetadata) -> dict:
    """metrics.json (DESIGN.md): mission, per-estimator, recognition and sonar blocks."""
    gt = metadata.ground_truth

    def seen(ids, all_):
        if gt is None:
            return None
        return len(ids) if ids is not None else len(all_)

    metrics = {
        "mission": {
            "duration_s": pipeline.duration_s,
            "gt_objects": seen(gt.seen_objects, gt.objects) if gt else None,
            "gt_pipes": seen(gt.seen_pipes, gt.pipes) if gt else None,
            "gt_structures": seen(gt.seen_structures, gt.structures) if gt else None,
        },
        "estimators": {},
        "recognition": {},
        "sonar": None,
        "timing_s": pipeline.timing_s,
    }
    for name, result in pipeline.results.items():
        runtime = pipeline.timing_s.get(f"estimator:{name}")
        metrics["estimators"][name] = estimator_metrics(result, pipeline.truth, gt, runtime)
        if _has_distinct_online(result):
            online = EstimatorResult(
                f"{name}_online",
                result.online_trajectory,
                result.landmarks,
                None,
                result.update_times_s,
                result.update_n_landmarks,
            )
            metrics["estimators"][f"{name}_online"] = estimator_metrics(online, pipeline.truth, gt, runtime)
    syn = None
    for summary in pipeline.frontend_summaries.values():
        if summary.section == "sonar":
            metrics["sonar"] = sonar_metrics(summary.metrics, gt)
        elif summary.section == "recognition":
            syn = summary.metrics.get("SYN")
        elif summary.section:
            metrics[summary.section] = summary.metrics
    metrics["recognition"] = recognition_block(pipeline, metadata, syn)
    return metrics


def write_outputs(out_dir: str | Path, config: SemslamConfig, pipeline: PipelineResult, metrics: dict) -> Path:
    """Write config.yaml, trajectory_<est>.tum, map_<est>.json/.ply and metrics.json into ``out_dir``."""
    import open3d as o3d

    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        # the resolved configuration: the front-ends' own sections with their defaults filled in
        resolved = config.model_copy(update={"frontends": {**config.frontends, **pipeline.frontend_configs}})
        (stage / "config.yaml").write_text(dump_config(resolved))
        for name, result in pipeline.results.items():
            result.trajectory.to_tum(stage / f"trajectory_{name}.tum")
            if _has_distinct_online(result):
                result.online_trajectory.to_tum(stage / f"trajectory_{name}_online.tum")
            (stage / f"map_{name}.json").write_text(json.dumps(map_to_dict(result), indent=1))
            o3d.io.write_triangle_mesh(str(stage / f"map_{name}.ply"), map_geometry(result.landmarks))
        for summary in pipeline.frontend_summaries.values():
            for name, writer in summary.files.items():
                writer(stage / name)
        (stage / "metrics.json").write_text(json.dumps(metrics, indent=2, default=_json_default))
        out_dir.mkdir(exist_ok=True)
        _move_into(stage, out_dir)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return out_dir


def _move_into(src: Path, dst: Path) -> None:
    """Move every entry of ``src`` into ``dst``, replacing files of the same name; a subdirectory
    (a front-end's ``figures/...``) is merged into an existing one rather than replacing it, so a
    run into an existing output directory works."""
    for f in src.iterdir():
        target = dst / f.name
        if f.is_dir() and target.is_dir():
            _move_into(f, target)
        else:
            f.replace(target)


def _json_default(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x)}")
