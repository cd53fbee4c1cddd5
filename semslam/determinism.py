"""One thread per numeric library for the length of a run, so that a mission gives the same result
on any machine (issue 21; experiments/estimators/README.md, stop 38)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def one_thread_per_library() -> Iterator[None]:
    """Inside the block, the numeric libraries of this process work on one thread each: BLAS and
    OpenMP (threadpoolctl) and Open3D's oneTBB (``open3d.utility.set_max_threads``; Open3D 0.20 has no
    OpenMP, ``OMP_NUM_THREADS`` does not reach it). Every way a mission is run enters it (the pipeline,
    its front-end workers), so that a mission gives the same observations and estimates on any
    machine: a parallel reduction (Open3D's ICP normal equations, residual sums) adds its terms in an
    order that depends on the thread count and, with work stealing, on the machine's load; the sonar's
    structure observations then differ in their last bits, and a run that feeds them back through the
    estimate can end elsewhere (issue 21; experiments/estimators/README.md, stop 38). GTSAM is built without TBB here, and
    kiss-icp takes its own ``max_num_threads`` (frontends/odometry)."""
    import open3d  # a dependency of every front-end that uses it; imported here, it is pinned before any use
    from threadpoolctl import threadpool_limits

    before = open3d.utility.get_max_threads()
    open3d.utility.set_max_threads(1)
    try:
        with threadpool_limits(limits=1):
            yield
    finally:
        open3d.utility.set_max_threads(before)
