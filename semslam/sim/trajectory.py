"""The vehicle's true motion: at rest on the surface, then descending while it starts to circle the
structure on an ellipse, always facing the structure centre, with a small roll/pitch wobble.

Position and linear velocity are analytic (the velocity is the exact time derivative of the
position, so integrating it reproduces the path). The body angular rate is the derivative of the
orientation by a central difference of the rotation (error O(h²) with h = 1 ms, below 1e-7 rad/s).

Frames: {W} NED, {B} x forward / y right / z down; R_WB = Rz(yaw)·Ry(pitch)·Rx(roll).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.sim.config import TrajectoryConfig


def smoothstep(u):
    """Quintic smoothstep S(u) on [0, 1] (zero 1st/2nd derivatives at both ends), its derivative
    dS/du and its integral ∫₀ᵘ S (continued linearly past u = 1)."""
    u = np.asarray(u, float)
    c = np.clip(u, 0.0, 1.0)
    S = c**3 * (10 - 15 * c + 6 * c**2)
    dS = 30 * c**2 * (1 - c) ** 2
    IS = c**4 * (2.5 - 3 * c + c**2) + np.maximum(u - 1.0, 0.0)
    return S, dS, IS


class MotionModel:
    """A true vehicle motion T_WB(t), ``t`` in seconds from the mission start: what the sensor models
    sample. Subclasses give ``position_velocity`` (analytic, the velocity the exact derivative of the
    position), ``rotation`` and ``duration``; the body rate and 4×4 poses follow from them."""

    @property
    def duration(self) -> float:
        raise NotImplementedError

    def position_velocity(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Body origin in {W} (N×3, m) and its velocity in {W} (N×3, m/s)."""
        raise NotImplementedError

    def rotation(self, t) -> Rotation:
        """R_WB(t)."""
        raise NotImplementedError

    def angular_rate(self, t, h: float = 1e-3) -> np.ndarray:
        """Body angular rate ω_B (N×3, rad/s): R_WB(t)ᵀ·Ṙ_WB(t) = [ω_B]×."""
        t = np.atleast_1d(np.asarray(t, float))
        Rm, Rp = self.rotation(t - h), self.rotation(t + h)
        return (Rm.inv() * Rp).as_rotvec() / (2 * h)

    def poses(self, t) -> np.ndarray:
        """T_WB(t) as N×4×4 matrices."""
        t = np.atleast_1d(np.asarray(t, float))
        T = np.tile(np.eye(4), (len(t), 1, 1))
        T[:, :3, :3] = self.rotation(t).as_matrix()
        T[:, :3, 3] = self.position_velocity(t)[0]
        return T


class Trajectory(MotionModel):
    """T_WB(t) of the simulated tank mission; ``t`` in seconds from the mission start."""

    def __init__(self, cfg: TrajectoryConfig, center: np.ndarray):
        self.cfg = cfg
        self.center = np.asarray(center, float)  # the point the vehicle faces (structure centre), {W}
        self.t_move = cfg.rest_s
        self.T = cfg.duration_s
        # θ(t) = θ0 + Ω·ramp·∫S: Ω chosen so that the mission ends after exactly `loops` loops.
        _, _, I_end = smoothstep((self.T - self.t_move) / cfg.ramp_s)
        self.omega = 2 * np.pi * cfg.loops / max(cfg.ramp_s * float(I_end), 1e-9)
        self.theta0 = np.deg2rad(cfg.start_angle_deg)

    @property
    def duration(self) -> float:
        return self.T

    # --- angle around the structure and depth

    def _theta(self, t):
        u = (np.asarray(t, float) - self.t_move) / self.cfg.ramp_s
        S, _, IS = smoothstep(u)
        return self.theta0 + self.omega * self.cfg.ramp_s * IS, self.omega * S

    def _ramp(self, t):
        S, dS, _ = smoothstep((np.asarray(t, float) - self.t_move) / self.cfg.ramp_s)
        return S, dS / self.cfg.ramp_s

    def position_velocity(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Body origin in {W} (N×3, m) and its velocity in {W} (N×3, m/s)."""
        t = np.atleast_1d(np.asarray(t, float))
        c = self.cfg
        a, b = c.semi_axes_m
        th, dth = self._theta(t)
        S, dS = self._ramp(t)
        x = self.center[0] + a * np.cos(th)
        y = self.center[1] + b * np.sin(th)
        vx = -a * np.sin(th) * dth
        vy = b * np.cos(th) * dth
        # depth: surface → working depth with the ramp, then a swing twice per loop
        k = 2.0
        dz_mean = c.work_depth_m - c.start_depth_m
        swing = c.depth_swing_m * np.sin(k * (th - self.theta0))
        z = c.start_depth_m + dz_mean * S + S * swing
        vz = dz_mean * dS + dS * swing + S * c.depth_swing_m * np.cos(k * (th - self.theta0)) * k * dth
        return np.stack([x, y, z], 1), np.stack([vx, vy, vz], 1)

    def _away(self, t) -> np.ndarray:
        """The heading turned away from the structure centre (rad): π inside ``look_away_s``, turned
        smoothly over ``look_away_turn_s`` at either end, 0 outside."""
        if self.cfg.look_away_s is None:
            return np.zeros_like(t)
        start, length = self.cfg.look_away_s
        turn = self.cfg.look_away_turn_s
        out, _, _ = smoothstep((t - start) / turn)
        back, _, _ = smoothstep((t - start - length + turn) / turn)
        return np.pi * (out - back)

    def rotation(self, t) -> Rotation:
        """R_WB(t): facing the structure centre (yaw; away from it during ``look_away_s``), with a small
        roll/pitch wobble."""
        t = np.atleast_1d(np.asarray(t, float))
        p, _ = self.position_velocity(t)
        yaw = np.arctan2(self.center[1] - p[:, 1], self.center[0] - p[:, 0]) + self._away(t)
        S, _ = self._ramp(t)
        A = np.deg2rad(self.cfg.roll_pitch_amplitude_deg)
        roll = A * S * np.sin(2 * np.pi * t / 7.3)
        pitch = A * S * np.sin(2 * np.pi * t / 11.1 + 0.7)
        return Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], 1))
