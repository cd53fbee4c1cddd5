"""A pipe's own end is not a fitting (issue 21, cause B of the tank's object twins).

The pipe stage cuts a pipe where a stretch of its surface stands a few mm out (a socket is 4.5 mm
wider than its pipe). At a free pipe end (no fitting), range noise on the sparse last centimetres and
a slightly tilted fit make such a stretch as often as a socket does; cut there, the pipe stopped
4-36 cm short of its end, and the rest of it, beyond the fitted end, was read as an object (12 of
the 16 extra object landmarks of 20 tank worlds). A bump beyond a pipe's outermost segment now cuts
it only when something besides the surface is there: a fitting's faces, body or branch off the
cylinder."""

import numpy as np

from frontends.laser.config import PipeConfig
from frontends.laser.grid import VoxelGrid
from frontends.laser.pipes import Rays, detect_pipes, split_at_fittings

R = 0.0315  # the tank's pipe radius


def _profile(seed: int, bump: float, sigma: float = 0.002):
    """Inliers of a pipe along t in [0, 0.5] (residuals with noise ``sigma``), its last 5 cm
    standing ``bump`` out."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0.0, 0.5, 500))
    residual = rng.normal(0.0, sigma, len(t)) + np.where(t > 0.45, bump, 0.0)
    return t, residual


def test_a_bump_at_a_free_pipe_end_does_not_cut_the_pipe_short():
    cfg = PipeConfig(radius_prior=R)
    for seed in range(5):
        t, residual = _profile(seed, 0.005)
        stray = np.random.default_rng(seed).uniform(0.0, 0.6, 4)  # a few points of clutter around
        runs = [r for r in split_at_fittings(t, residual, np.zeros(0), cfg, stray) if len(r) >= cfg.min_points]
        assert len(runs) == 1 and t[runs[0]].max() > 0.49  # the pipe runs to its end


def test_a_bump_with_a_body_beyond_it_is_still_a_fitting():
    cfg = PipeConfig(radius_prior=R)
    for seed in range(5):
        t, residual = _profile(seed, 0.005)
        body = np.random.default_rng(seed).uniform(0.47, 0.58, 30)  # a valve body's faces off the cylinder
        runs = [r for r in split_at_fittings(t, residual, np.zeros(0), cfg, body) if len(r) >= cfg.min_points]
        assert len(runs) == 1 and 0.43 < t[runs[0]].max() < 0.465  # cut where the fitting starts
    # and where what lies around is not known (t_around None), as before: cut
    t, residual = _profile(0, 0.005)
    (run,) = split_at_fittings(t, residual, np.zeros(0), cfg)
    assert t[run].max() < 0.465


def _free_pipe(seed: int, sigma: float):
    """A ray-cast-like half shell of a pipe along +x (x in [0, 0.5], axis at z = 2 m below the
    sensor), 1 cm voxels, its last 5 cm 5 mm wider (noise of the sparse end and a tilted fit, as the
    pipe stage sees it): (points, outward normals, grid, the scan's rays with a floor 0.5 m below)."""
    rng = np.random.default_rng(seed)
    n = 6000
    x = rng.uniform(0.0, 0.5, n)
    th = rng.uniform(-1.3, 1.3, n)
    r = R + np.where(x > 0.45, 0.005, 0.0) + rng.normal(0.0, sigma, n)
    raw = np.column_stack([x, r * np.sin(th), 2.0 - r * np.cos(th)])
    grid = VoxelGrid(raw, 0.01)
    p = grid.points
    radial = np.column_stack([np.zeros(len(p)), p[:, 1], p[:, 2] - 2.0])
    # the floor behind, where the sensor's rays past the pipe (and past its end) return
    fx, fy = np.meshgrid(np.arange(-0.3, 0.9, 0.01), np.arange(-0.3, 0.3, 0.01))
    floor = np.column_stack([fx.ravel(), fy.ravel(), np.full(fx.size, 2.5)])
    hidden = (np.abs(floor[:, 1] * 2.0 / 2.5) < R) & (floor[:, 0] * 2.0 / 2.5 > 0.0) & (floor[:, 0] * 2.0 / 2.5 < 0.5)
    return p, radial / np.linalg.norm(radial, axis=1)[:, None], grid, Rays(np.vstack([raw, floor[~hidden]]))


def test_detect_pipes_runs_a_free_pipe_to_its_end():
    for see_through in (False, True):  # the sensor sees the floor past the pipe's end
        cfg = PipeConfig(radius_prior=R, end_see_through=see_through)
        for seed in range(3):
            points, normals, grid, rays = _free_pipe(seed, 0.002)
            (pipe,) = [p for p in detect_pipes(points, normals, grid, cfg, rays) if p.length >= cfg.min_detect_length]
            lo, hi = sorted((pipe.p[0], pipe.q[0]))
            assert lo < 0.01 and hi > 0.49  # not stopped 5 cm short, the rest left to the objects
