"""The recognition tables of a mission run (the paper's Tables 3–4): SYN from the recogniser's
calibration, DESC / BAYS / SEM from the object observations the front-ends produced, scored against
the ground truth and fused by the landmark ids of the estimator the front-ends saw."""

from __future__ import annotations

from collections.abc import Iterator
from itertools import chain, islice

import numpy as np

from semslam.mapping.book import view_key
from semslam.mission.mission import MissionMetadata
from semslam.results import PipelineResult
from semslam.semantics.metrics import ObservationRecord, recognition_metrics

MATCH_GATE_M = 0.10  # an object observation farther than this from every true object is a false segment
RECORD_CHUNK = 1024  # labelled views placed at once (their Python objects, and a chunk × true objects of distances)


def _true_poses(truth, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """R_WB (N,3,3) and t_WB (N,3) of the ground truth at ``stamps`` (nearest sample)."""
    from scipy.spatial.transform import Rotation

    if truth is None or len(truth) == 0:
        return None
    idx = np.clip(np.searchsorted(truth.stamps, stamps), 1, len(truth.stamps) - 1)
    idx = np.where(np.abs(truth.stamps[idx - 1] - stamps) < np.abs(truth.stamps[idx] - stamps), idx - 1, idx)
    return Rotation.from_quat(truth.orientations[idx]).as_matrix(), truth.positions[idx]


def labelled_object_records(
    pipeline: PipelineResult, metadata: MissionMetadata, view: str = "graph"
) -> list[ObservationRecord]:
    """Every object observation with a class likelihood (``pipeline.labelled``), its true class
    (nearest true object to the observation placed with the true pose, within ``MATCH_GATE_M``) and
    the landmark id it ended in (the estimator's ``landmark_of_observation``, by view key)."""
    return list(iter_labelled_object_records(pipeline, metadata, view))


def iter_labelled_object_records(
    pipeline: PipelineResult, metadata: MissionMetadata, view: str = "graph"
) -> Iterator[ObservationRecord]:
    """:func:`labelled_object_records` one at a time, the views read and placed ``RECORD_CHUNK`` at a
    time: a long survey's tens of thousands of views are never all Python objects at once."""
    gt = metadata.ground_truth
    truth = pipeline.truth
    if gt is None or not gt.objects or not len(pipeline.labelled) or truth is None or len(truth) == 0:
        return
    result = pipeline.results.get(view) or next(iter(pipeline.results.values()))
    landmark_of = result.history.get("landmark_of_observation", {})
    truth_pos = gt.object_positions()
    truth_cls = [o.cls for o in gt.objects]
    views = iter(pipeline.labelled)
    while obs := list(islice(views, RECORD_CHUNK)):
        R_WB, t_WB = _true_poses(truth, np.array([r.stamp for r in obs], np.int64))
        # every view placed in {W} with the true pose at once, sensor by sensor
        in_body = np.empty((len(obs), 3))
        sensors = [r.sensor for r in obs]
        for sensor in set(sensors):
            rows = [k for k, s in enumerate(sensors) if s == sensor]
            info = metadata.sensors.get(sensor)
            T_BS = info.T_BS if info is not None else np.eye(4)
            in_body[rows] = np.array([obs[k].position for k in rows], float) @ T_BS[:3, :3].T + T_BS[:3, 3]
        w = np.einsum("nij,nj->ni", R_WB, in_body) + t_WB
        d = np.linalg.norm(w[:, None, :] - truth_pos[None, :, :], axis=2)
        nearest = np.argmin(d, axis=1)
        for r, k, dk in zip(obs, nearest, d[np.arange(len(obs)), nearest]):
            if dk > MATCH_GATE_M:
                continue
            lid = landmark_of.get(view_key(r.view_stamp, r.sensor, r.position))
            yield ObservationRecord(truth_cls[k], r.class_likelihood, lid, r.configuration)


def recognition_block(
    pipeline: PipelineResult, metadata: MissionMetadata, syn: dict | None = None, view: str = "graph"
) -> dict:
    """metrics.json's "recognition" block: ``syn`` is the recogniser's own SYN entry (if any)."""
    out: dict = {}
    records = iter_labelled_object_records(pipeline, metadata, view)
    first = next(records, None)
    if first is not None:  # the records streamed (a long survey has tens of thousands), never all kept
        classes = list(metadata.ground_truth.classes) or sorted(
            {r.true_class for r in iter_labelled_object_records(pipeline, metadata, view)}
        )
        stages = recognition_metrics(chain([first], records), classes, mode="online")
        out = {k: v for k, v in stages.items() if k != "SYN" and v is not None}
    if syn:
        out = {"SYN": syn, **out}
    return out
