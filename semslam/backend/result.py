"""The graph back-end's result at the end of a mission: the final estimate (the online one, or the
batch re-optimisation of the whole mission), the keyframe trajectory with marginal covariances, and
each keyframe as the online smoother gave it at its time."""

from __future__ import annotations

import time

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from semslam.backend.session import IsamSession
from semslam.backend.window import LEFT_COVARIANCE_EVERY, SlidingWindow, V, X
from semslam.config import GraphConfig
from semslam.errors import solver_failure
from semslam.estimation import Trajectory


def final_values(
    session: IsamSession, window: SlidingWindow, cfg: GraphConfig, batch: bool, history: dict
) -> gtsam.Values:
    """The online estimate of every variable (frozen ones included) or, with ``batch``, Levenberg–
    Marquardt over the whole mission from it (its time in ``history["batch_time_s"]``)."""
    online = window.estimate(session)
    if not batch:
        return online
    t0 = time.perf_counter()
    try:
        values = session.batch(online, cfg.batch_max_iterations)
    except RuntimeError as exc:
        session.diagnostics.append(f"batch optimisation failed ({solver_failure(exc)}); online estimate kept")
        values = online
    history["batch_time_s"] = time.perf_counter() - t0
    return values


def _quaternions(rotations) -> np.ndarray:
    """(x, y, z, w) of each 3×3 rotation matrix."""
    return np.array([Rotation.from_matrix(R).as_quat() for R in rotations])


def keyframe_trajectory(
    stamps: list[int],
    values: gtsam.Values,
    marginals,
    session: IsamSession,
    cfg: GraphConfig,
    known: dict[int, np.ndarray] | None = None,
) -> Trajectory:
    """Every keyframe's pose and velocity in ``values``; with ``cfg.covariance_in_result`` the marginal
    covariances of ``result_covariance_keyframes`` evenly spaced ones (NaN between). Those in ``known``
    (keyframes that left the window, which kept the covariance of some only) are given; a sampled
    keyframe that left without one is replaced by the nearest that kept one."""
    n = len(stamps)
    poses = [values.atPose3(X(i)) for i in range(n)]
    pos_cov = vel_cov = None
    if cfg.covariance_in_result:
        pos_cov = np.full((n, 3, 3), np.nan)
        vel_cov = np.full((n, 3, 3), np.nan)
        sample = np.linspace(0, n - 1, min(n, cfg.result_covariance_keyframes)).round().astype(int)
        sample = np.unique(_nearest_known(sample, n, known or {}))
        covs = session.joint_blocks(marginals, [k for i in sample for k in (X(i), V(i))], known=known)
        for i in sample:
            if X(i) in covs and V(i) in covs:
                R = poses[i].rotation().matrix()
                pos_cov[i] = R @ covs[X(i)][3:, 3:] @ R.T
                vel_cov[i] = covs[V(i)]
    return Trajectory(
        stamps=np.array(stamps, np.int64),
        positions=np.array([p.translation() for p in poses]),
        orientations=_quaternions([p.rotation().matrix() for p in poses]),
        position_cov=pos_cov,
        velocities=np.array([values.atVector(V(i)) for i in range(n)]),
        velocity_cov=vel_cov,
    )


def _nearest_known(sample: np.ndarray, n: int, known: dict[int, np.ndarray]) -> np.ndarray:
    """``sample`` with each keyframe that left the window (one in ``LEFT_COVARIANCE_EVERY`` of those
    kept its covariance: the window starts at most that far after the newest in ``known``) moved to
    the nearest keyframe whose pose covariance ``known`` holds."""
    kept = np.array(sorted(i for i in range(n) if X(i) in known), int)
    if not kept.size:
        return sample
    out = sample.copy()
    old = sample < kept[-1] + LEFT_COVARIANCE_EVERY
    j = np.clip(np.searchsorted(kept, sample[old]), 1, max(kept.size - 1, 1))
    lo, hi = kept[j - 1], kept[np.minimum(j, kept.size - 1)]
    out[old] = np.where(np.abs(sample[old] - lo) <= np.abs(hi - sample[old]), lo, hi)
    return out


def online_trajectory(online: np.ndarray) -> Trajectory:
    """Each keyframe as the online smoother gave it at its time, with its position covariance then
    (``online``: :data:`~semslam.backend.keyframes.ONLINE_ROW` rows)."""
    return Trajectory(
        stamps=np.array(online["stamp"], np.int64),
        positions=np.array(online["t"]),
        orientations=_quaternions(online["R"]),
        position_cov=np.array(online["position_cov"]),
    )
