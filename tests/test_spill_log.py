"""What a run appends for hours (the ground truth, the labelled views, the landmarks' volumes) is
kept on disk as it comes (issue 26): read back exactly as appended, in memory only a chunk of it,
and in no file anyone can see."""

import os
import tracemalloc

import numpy as np
import pytest

from semslam.backend.landmarks import VolumeLog
from semslam.estimation import SpillLog
from semslam.observations import Connectivity, PointObservation
from semslam.results import LabelledViews, PoseLog

ROW = [("stamp", "<i8"), ("xyz", "<f8", 3)]


def test_rows_come_back_as_appended_across_chunks_and_the_log_goes_on(tmp_path):
    log = SpillLog(ROW, chunk=7, directory=tmp_path)
    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(50, 3)) * 1e6
    for i in range(30):
        log.append(i * 1_000_000_007, xyz[i])
    first = log.array()
    for i in range(30, 50):  # reading back does not end the log
        log.append(i * 1_000_000_007, xyz[i])
    rows = log.array()
    assert len(log) == len(rows) == 50 and len(first) == 30
    assert np.array_equal(rows["stamp"], np.arange(50) * 1_000_000_007)
    assert np.array_equal(rows["xyz"], xyz)  # bit for bit
    assert np.array_equal(rows[:30], first)
    assert len(SpillLog(ROW).array()) == 0


def test_the_rows_are_in_no_file_a_directory_lists(tmp_path):
    log = SpillLog(ROW, chunk=4, directory=tmp_path)
    for i in range(100):
        log.append(i, (i, i, i))
    assert len(log.array()) == 100
    assert os.listdir(tmp_path) == []  # nothing half-written to see, nothing to clean after a crash


def test_a_failed_spill_fails_the_same_way_on_every_later_row(tmp_path, monkeypatch):
    """A full disk: the row that fills the chunk raises SpillError, and so does any row a cleanup
    appends after it (not an IndexError past the full chunk, which would print a traceback)."""
    import semslam.estimation as estimation

    class FullDisk:
        def __init__(self, **kwargs):
            pass

        def write(self, data):
            raise OSError(28, "No space left on device")

    monkeypatch.setattr(estimation, "TemporaryFile", FullDisk)
    log = SpillLog(ROW, chunk=4, directory=tmp_path)
    for i in range(3):
        log.append(i, (i, i, i))
    for i in range(3, 6):
        with pytest.raises(estimation.SpillError, match="No space left on device"):
            log.append(i, (i, i, i))
    assert len(log) == 4


def test_memory_held_is_a_chunk_not_the_rows(tmp_path):
    n, chunk = 100_000, 1000
    log = SpillLog(ROW, chunk=chunk, directory=tmp_path)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for i in range(n):
            log.append(i, (0.5, 1.5, 2.5))
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert n * log.dtype.itemsize == 3_200_000  # what a list or array in memory would hold at least
    assert held < 100_000, held
    assert log.array()["stamp"][-1] == n - 1


def test_poses_come_back_as_a_trajectory(tmp_path):
    log = PoseLog(tmp_path)
    assert log.trajectory() is None
    rng = np.random.default_rng(0)
    p, q = rng.normal(size=(9000, 3)), rng.normal(size=(9000, 4))  # more than one chunk
    for i in range(9000):
        log.append(10 * i, p[i], q[i])
    traj = log.trajectory()
    assert len(log) == len(traj) == 9000
    assert np.array_equal(traj.stamps, 10 * np.arange(9000))
    assert np.array_equal(traj.positions, p) and np.array_equal(traj.orientations, q)
    assert traj.stamps.dtype == np.int64 and traj.positions.flags.c_contiguous


def test_labelled_views_come_back_with_their_numbers(tmp_path):
    views = LabelledViews(tmp_path)
    classes = ({"valve": 0.7, "tee": 0.3}, {"flange": 0.1, "valve": 0.2, "elbow": 0.7})
    made = []
    for i in range(5000):  # more than one chunk of rows and of scores
        z = PointObservation(
            stamp=i + 3,
            sensor=("laser", "sonar")[i % 2],
            position=(i, -i, 0.25 * i),
            class_likelihood=classes[i % 3 == 0],
            connectivity=Connectivity(n_pipes=2, configuration=3) if i % 4 == 0 else None,
        )
        views.append(i, z)
        made.append(z)
    back = list(views)
    assert len(views) == len(back) == 5000
    for i, (v, z) in enumerate(zip(back, made)):
        assert (v.stamp, v.view_stamp, v.sensor) == (i, z.stamp, z.sensor)
        assert np.array_equal(v.position, z.position)
        assert v.class_likelihood == z.class_likelihood and list(v.class_likelihood) == list(z.class_likelihood)
        assert v.configuration == (3 if i % 4 == 0 else None)


def test_each_landmarks_volumes_in_the_order_logged_without_the_removed():
    log = VolumeLog()
    for lid, stamp, value in [(5, 1, 0.5), (2, 1, -1.0), (5, 2, 0.25), (7, 3, 9.0), (2, 4, -2.0)]:
        log.append(lid, stamp, value)
    log.pop(7)
    assert log.items() == [(5, [(1, 0.5), (2, 0.25)]), (2, [(1, -1.0), (4, -2.0)])]
    assert VolumeLog().items() == []


@pytest.mark.parametrize("n", [4095, 4096, 4097])
def test_a_log_ending_at_a_chunks_edge_loses_nothing(n, tmp_path):
    log = SpillLog("<f8", directory=tmp_path)
    for i in range(n):
        log.append(float(i))
    assert np.array_equal(log.array(), np.arange(n, dtype=float))
