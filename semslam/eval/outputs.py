"""The output directory of DESIGN.md: config, TUM trajectories, semantic maps (JSON + PLY), metrics,
and (compare, demo) the report and (``--record``) the replay.

An output directory appears whole or not at all: :func:`staged_output` stages everything in a
hidden sibling directory (same file system) and renames it into place at the end; an existing
directory is refused unless ``overwrite``, which replaces it whole. :func:`check_output_dir` says
before a run whether its output could be written at all. A command opens the stage before its
pipeline runs: the run's spill files (:class:`semslam.estimation.SpillLog`) go into a hidden
directory of the stage (:data:`SPILL_DIR`), on the output's filesystem, removed before the rename.
"""

from __future__ import annotations

import errno
import fcntl
import glob
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from semslam.collector import heap_frozen
from semslam.config import SemslamConfig, dump_config
from semslam.errors import SemslamError
from semslam.estimation import EstimatorResult, LandmarkEstimate, spilling_into
from semslam.eval.metrics import estimator_metrics, sonar_metrics
from semslam.eval.recognition import recognition_block
from semslam.mission.mission import MissionMetadata
from semslam.results import OBSERVATION_MAPS, PipelineResult

# What marks a directory as a semslam output (every run writes it): only such a directory is replaced.
MARKER_FILE = "metrics.json"
# The stage's directory of the run's spill files (anonymous: it lists none), removed before the rename.
SPILL_DIR = ".spill"
STAGE_SUFFIX = ".partial"  # a stage is ".<output's name>.<random>.partial" beside the output


class OutputError(SemslamError):
    """The output directory cannot be written (a file in the way, no permission, disk full, ...)."""


def _os_error(path: Path, exc: OSError, stage: Path | None = None) -> OutputError:
    """One line naming the file (as the user will know it: inside ``path``, not the hidden ``stage``
    it was written into) and the reason."""
    where = Path(exc.filename) if exc.filename else path
    if not exc.filename and stage is not None:  # a failed write() (a full disk) names no file: the
        where = _newest_file(stage) or path  # one being written is the last one opened
    if stage is not None and where.is_relative_to(stage):
        where = path / where.relative_to(stage)
    reason = exc.strerror or str(exc)
    return OutputError(f"{where}: cannot write the output ({reason})")


def _newest_file(directory: Path) -> Path | None:
    files = [p for p in directory.rglob("*") if p.is_file()]
    return max(files, key=lambda p: p.stat().st_mtime_ns, default=None)


def check_output_dir(out_dir: str | Path, overwrite: bool = False) -> Path:
    """Refuse, before any work, an output directory that could not be written: a file in the way,
    an existing directory without ``overwrite`` (or one that is no semslam output), a parent that
    cannot be created or written. Returns the path."""
    out_dir = Path(out_dir)
    if out_dir.exists() or out_dir.is_symlink():
        if not out_dir.is_dir():
            raise OutputError(f"{out_dir}: exists and is not a directory")
        if not overwrite:
            raise OutputError(f"{out_dir}: exists already (--overwrite replaces it)")
        if any(out_dir.iterdir()) and not (out_dir / MARKER_FILE).is_file():
            raise OutputError(f"{out_dir}: not a semslam output directory (no {MARKER_FILE}); not replacing it")
    ancestor = next(p for p in out_dir.parents if p.exists() or p.is_symlink())
    if not ancestor.is_dir():  # mkdir would only say "File exists"
        raise OutputError(f"{ancestor}: exists and is not a directory")
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        probe = tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".probe", dir=out_dir.parent)
        os.rmdir(probe)
    except OSError as exc:
        raise _os_error(out_dir.parent, exc) from None
    return out_dir


@contextmanager
def staged_output(out_dir: str | Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a staging directory to write an output into; on leaving the block without error it
    becomes ``out_dir`` (replacing an existing one only with ``overwrite``); on any error it is
    removed and ``out_dir`` is left as it was. OSErrors on the output (a file of the stage or beside
    ``out_dir``, or one naming no file once the output is being written) become one-line
    :class:`OutputError`s; others pass unchanged.

    Open it before the run: every spill file opened in the block
    (:func:`semslam.estimation.spilling_into`) goes into the stage's hidden :data:`SPILL_DIR`, on
    the output's filesystem, and a full disk there is one line naming ``out_dir``."""
    out_dir = check_output_dir(out_dir, overwrite)
    _remove_abandoned_stages(out_dir)
    lock = None
    try:
        stage = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=STAGE_SUFFIX, dir=out_dir.parent))
        lock = _lock(stage)
    except OSError as exc:
        if lock is not None:
            os.close(lock)
        raise _os_error(out_dir.parent, exc) from None
    try:
        try:
            with spilling_in_stage(stage, named=out_dir):  # a full disk there: one line naming out_dir
                yield stage
            umask = os.umask(0)
            os.umask(umask)
            stage.chmod(0o777 & ~umask)  # mkdtemp's 0700 would make a private output
            _commit(stage, out_dir, overwrite)
        except OSError as exc:
            if not _on_the_output(exc, out_dir, stage):
                raise
            raise _os_error(out_dir, exc, stage) from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        os.close(lock)


@contextmanager
def spilling_in_stage(stage: Path, named: Path) -> Iterator[None]:
    """Every spill file opened in the block goes into ``stage``'s hidden :data:`SPILL_DIR` (made here,
    removed when the block ends without error); a full disk there is one line naming ``named``."""
    spill = stage / SPILL_DIR
    spill.mkdir()
    with spilling_into(spill, named=named):
        yield
    shutil.rmtree(spill)  # empty: the spill files are anonymous (they live on while open)


def _lock(stage: Path) -> int:
    """Hold ``stage`` for this process (released when it ends, however: SIGKILL too); the descriptor."""
    fd = os.open(stage, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise
    return fd


def _remove_abandoned_stages(out_dir: Path) -> None:
    """The stages of earlier runs into ``out_dir`` that no process holds any more: a run killed with
    SIGKILL (or a machine that stopped) cannot remove its own, hidden but taking room beside the output."""
    for stage in out_dir.parent.glob(f".{glob.escape(out_dir.name)}.*{STAGE_SUFFIX}"):
        try:
            fd = _lock(stage)
        except OSError:  # held by a running run (or gone meanwhile)
            continue
        try:
            shutil.rmtree(stage, ignore_errors=True)
        finally:
            os.close(fd)


def _on_the_output(exc: OSError, out_dir: Path, stage: Path) -> bool:
    """Whether ``exc`` is a failure of the output (not of the run inside the block, e.g. reading
    the mission): it names a file of the stage, ``out_dir`` or a hidden sibling of it; or it names
    none (a failed write() on a full disk) and the output is being written (the stage holds a file)."""
    if not exc.filename:
        return _newest_file(stage) is not None
    where = Path(os.path.abspath(exc.filename))
    out = Path(os.path.abspath(out_dir))
    return (
        where.is_relative_to(os.path.abspath(stage))
        or where.is_relative_to(out)
        or (where.parent == out.parent and where.name.startswith(f".{out.name}."))
    )


def _commit(stage: Path, out_dir: Path, overwrite: bool) -> None:
    """Rename ``stage`` to ``out_dir``; an existing ``out_dir`` (with ``overwrite``) is moved aside
    first and removed after, so the new output never mixes with the old."""
    try:
        os.rename(stage, out_dir)  # replaces at most an empty directory
        return
    except OSError as exc:
        if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
            raise
    check_output_dir(out_dir, overwrite)  # it appeared during the run: the same rules as before it
    old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".old", dir=out_dir.parent))
    moved = old / out_dir.name
    try:
        os.rename(out_dir, moved)
        os.rename(stage, out_dir)
    except BaseException:  # an error, or a signal between the two renames: the old one goes back
        if moved.exists() and not out_dir.exists():
            os.rename(moved, out_dir)
        raise
    finally:
        if out_dir.exists() or not moved.exists():  # never delete the only copy of the old output
            shutil.rmtree(old, ignore_errors=True)


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


@heap_frozen()
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
            metrics["sonar"] = sonar_metrics(summary.metrics, gt, pipeline.truth)
        elif summary.section == "recognition":
            syn = summary.metrics.get("SYN")
        elif summary.section:
            metrics[summary.section] = summary.metrics
    metrics["recognition"] = recognition_block(pipeline, metadata, syn)
    return metrics


@heap_frozen()
def write_results(directory: Path, config: SemslamConfig, pipeline: PipelineResult, metrics: dict) -> None:
    """Write config.yaml, trajectory_<est>.tum, map_<est>.json/.ply, the front-ends' files and
    metrics.json into ``directory`` (a staging directory: see :func:`staged_output`)."""

    directory = Path(directory)
    # the resolved configuration: the front-ends' own sections with their defaults filled in
    resolved = config.model_copy(update={"frontends": {**config.frontends, **pipeline.frontend_configs}})
    (directory / "config.yaml").write_text(dump_config(resolved))
    for name, result in pipeline.results.items():
        result.trajectory.to_tum(directory / f"trajectory_{name}.tum")
        if _has_distinct_online(result):
            result.online_trajectory.to_tum(directory / f"trajectory_{name}_online.tum")
        if name in OBSERVATION_MAPS:
            (directory / f"map_{name}.json").write_text(json.dumps(observation_map_to_dict(result), indent=0))
            write_observation_ply(directory / f"map_{name}.ply", result.landmarks)
        else:
            (directory / f"map_{name}.json").write_text(json.dumps(map_to_dict(result), indent=1))
            write_mesh(directory / f"map_{name}.ply", map_geometry(result.landmarks))
    for summary in pipeline.frontend_summaries.values():
        for name, writer in summary.files.items():
            target = directory / name
            target.parent.mkdir(parents=True, exist_ok=True)
            writer(target)
    (directory / "metrics.json").write_text(json.dumps(metrics, indent=2, default=_json_default))


def write_mesh(path: Path, mesh) -> None:
    """An open3d triangle mesh (vertices, colours, triangles) as binary PLY, written here rather
    than by open3d: its writer prints every failed element to stderr and may still report success
    (a full disk), and writes no file at all for an empty mesh."""
    colors = np.asarray(mesh.vertex_colors) if mesh.has_vertex_colors() else np.full((len(mesh.vertices), 3), 0.7)
    write_ply(path, np.asarray(mesh.vertices), colors, faces=np.asarray(mesh.triangles))


def write_ply(path: Path, points, colors, faces=(), edges=(), comment: str = "") -> None:
    """Binary PLY: vertices (N×3) with RGB colours in [0, 1] (N×3), triangles (M×3 vertex indices)
    and edges (K×2); an OSError (a full disk) is raised as any file write's."""
    xyz = np.asarray(points, float).reshape(-1, 3)
    rgb = (255 * np.clip(np.asarray(colors, float).reshape(-1, 3), 0, 1)).round()
    vertex = np.zeros(len(xyz), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    for k, c in enumerate("xyz"):
        vertex[c] = xyz[:, k]
    for k, c in enumerate("rgb"):
        vertex[c] = rgb[:, k]
    tri = np.asarray(faces, "<i4").reshape(-1, 3)
    face = np.zeros(len(tri), [("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, tri
    edge = np.asarray(edges, "<i4").reshape(-1, 2)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        + (f"comment {comment}\n" if comment else "")
        + f"element vertex {len(vertex)}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        f"element face {len(face)}\nproperty list uchar int vertex_indices\n"
        f"element edge {len(edge)}\nproperty int vertex1\nproperty int vertex2\nend_header\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vertex.tobytes())
        f.write(face.tobytes())
        f.write(edge.tobytes())


def write_outputs(
    out_dir: str | Path, config: SemslamConfig, pipeline: PipelineResult, metrics: dict, overwrite: bool = True
) -> Path:
    """:func:`write_results` as one transaction into ``out_dir``: an existing semslam output there is
    replaced whole (``overwrite``, the library's default; the commands ask the user)."""
    with staged_output(out_dir, overwrite) as stage:
        write_results(stage, config, pipeline, metrics)
    return Path(out_dir)


def write_staged(
    stage: Path,
    config: SemslamConfig,
    pipeline: PipelineResult,
    metrics: dict,
    metadata: MissionMetadata,
    *,
    report: bool = False,
    recorder=None,
) -> None:
    """A command's whole output into the stage of the :func:`staged_output` block it opened before its
    run (so that the run spilled into it): the results, the report (``report``: report.md,
    report.html, figures/) and the replay (a :class:`semslam.eval.replay.ReplayRecorder` that
    watched the run: replay.mcap and its Foxglove layout)."""
    write_results(stage, config, pipeline, metrics)
    if recorder is not None:
        from semslam.eval.replay import LAYOUT_FILE, LAYOUT_PATH, REPLAY_FILE

        recorder.write(stage / REPLAY_FILE, pipeline)
        shutil.copyfile(LAYOUT_PATH, stage / LAYOUT_FILE)
    if report:
        from semslam.eval.report import write_report

        write_report(stage, pipeline, metadata, metrics, replay=recorder is not None)


def observation_map_to_dict(result: EstimatorResult, decimals: int = 4) -> dict:
    """A map of placed observations (:data:`semslam.results.OBSERVATION_MAPS`) as what it is: one row per
    observation, objects ``[x, y, z, class]`` and pipes ``[px, py, pz, qx, qy, qz]`` in {W}."""
    objects, pipes = [], []
    for lm in result.landmarks:
        if lm.kind == "object" and lm.position is not None:
            post = lm.class_posterior or {}
            cls = max(post, key=post.get) if post else None
            objects.append([*np.round(np.asarray(lm.position, float), decimals).tolist(), cls])
        elif lm.kind == "pipe" and lm.p is not None:
            pipes.append(np.round(np.concatenate([lm.p, lm.q]).astype(float), decimals).tolist())
    return {
        "estimator": result.name,
        "map": "observations",
        "note": "every observation placed with the estimator's own pose, never merged into landmarks",
        "objects": objects,
        "pipes": pipes,
    }


def write_observation_ply(path: Path, landmarks: list[LandmarkEstimate]) -> None:
    """Placed observations as a binary PLY of vertices and edges (what open3d's types cannot hold
    together with vertex colours): object observations as vertices coloured by class, pipe
    observations as edges between their two (pipe-coloured) end vertices."""
    from semslam.eval.replay_scene import PIPE_RGB, class_rgb, map_class

    points, colors, edges = [], [], []
    for lm in landmarks:
        if lm.kind == "object" and lm.position is not None:
            points.append(lm.position)
            colors.append(class_rgb(map_class(lm.class_posterior)[0]))
        elif lm.kind == "pipe" and lm.p is not None:
            edges.append((len(points), len(points) + 1))
            points += [lm.p, lm.q]
            colors += [PIPE_RGB, PIPE_RGB]
    write_ply(path, points, colors, edges=edges, comment="semslam: observations placed with the estimator's pose")


def _json_default(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x)}")
