"""A mission gives the same result whatever the machine's core count or load: inside a pipeline run,
in the driver and in the front-end workers, the numeric libraries work on one thread each
(semslam.determinism.one_thread_per_library). Open3D 0.20 parallelises with oneTBB: a
reduction's last bits (an ICP's residual sums) depend on its thread count and, with work stealing,
on timing; a borderline decision of the sonar front-end flipped with them (issue 21, stop 38)."""

from typing import ClassVar

import numpy as np
import open3d as o3d

from semslam.config import SemslamConfig
from semslam.ekf import EkfEstimator
from semslam.mission.measurements import Depth
from semslam.pipeline import run_pipeline
from semslam.registry import Frontend, FrontendSummary


def _icp() -> tuple[float, ...]:
    """A point-to-plane ICP of a noisy, shifted copy of a bumpy surface: its transform, fitness and
    inlier RMSE to the last bit (Open3D sums the normal equations and the RMSE in parallel)."""
    rng = np.random.default_rng(0)
    xy = rng.uniform(-5, 5, (20000, 2))
    P = np.c_[xy, 0.3 * np.sin(xy[:, 0]) * np.cos(0.7 * xy[:, 1]) + 0.01 * rng.standard_normal(len(xy))]
    tgt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    tgt.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(12))
    Q = P[::2] + [0.05, -0.03, 0.02] + 0.02 * rng.standard_normal((len(P[::2]), 3))
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(Q))
    reg = o3d.pipelines.registration
    est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=0.1))
    res = reg.registration_icp(src, tgt, 0.3, np.eye(4), est, reg.ICPConvergenceCriteria(1e-9, 1e-9, 20))
    return (*np.asarray(res.transformation).ravel().tolist(), res.fitness, res.inlier_rmse)


def _threads() -> dict:
    from threadpoolctl import threadpool_info

    return {"open3d": o3d.utility.get_max_threads(), "pools": sorted({p["num_threads"] for p in threadpool_info()})}


class ThreadProbe(Frontend):
    """On each of the first depth readings: Open3D's thread limit, threadpoolctl's pools and an ICP's
    result, in the process it runs in; reported by ``finish``."""

    name: ClassVar[str] = "probe_inline"
    consumes: ClassVar[tuple] = (Depth,)

    def __init__(self):
        self.seen: list = []

    def process(self, measurement, view):
        if len(self.seen) < 3:
            self.seen.append((_threads(), _icp()))
        return []

    def finish(self, view=None):
        return FrontendSummary(section=self.name, metrics={"seen": self.seen})


class ThreadProbeApart(ThreadProbe):
    """The same in a front-end worker process."""

    name: ClassVar[str] = "probe_apart"
    uses_view: ClassVar[bool] = False


def test_one_thread_per_library_in_the_driver_and_the_workers(sample_mission):
    """Whatever the caller's setting (here Open3D allowed 2 threads), a run's front-ends, inline and
    in their workers, see one thread per library, and their ICP gives the single-threaded result to
    the last bit; the caller's setting is back afterwards. Without the pin, Open3D's TBB uses every
    core (2 here): the ICP's RMSE differs in its last bits (and from run to run)."""
    o3d.utility.set_max_threads(1)
    reference = _icp()
    o3d.utility.set_max_threads(2)
    callers = o3d.utility.get_max_threads()
    try:
        mission = sample_mission(seconds=3.0)
        res = run_pipeline(
            mission, [EkfEstimator(mission.metadata, SemslamConfig())], [ThreadProbe(), ThreadProbeApart()]
        )
        assert o3d.utility.get_max_threads() == callers
    finally:
        o3d.utility.set_max_threads(0)
    for name in ("probe_inline", "probe_apart"):
        seen = res.frontend_summaries[name].metrics["seen"]
        assert len(seen) == 3, name
        for threads, icp in seen:
            assert threads == {"open3d": 1, "pools": [1]}, (name, threads)
            assert tuple(icp) == reference, name
