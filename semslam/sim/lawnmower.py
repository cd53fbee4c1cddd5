"""The field vehicle's true motion: an east–west lawnmower survey at constant depth and speed.

Lines run east or west, the first at the south heading east, each next one ``line_spacing_m``
further north; consecutive lines are joined by a half-turn at constant speed whose yaw rate rises
from zero by a quintic smoothstep, holds, and falls back to zero (a smooth turn: no jump in yaw
rate nor in its derivative). The turn's length makes its lateral offset exactly one line
spacing; its along-track excursion returns to zero by symmetry, so every line starts where the
previous one ended, one spacing north.

Position and velocity are those of a point moving at constant speed along that path: the
velocity v·(cos ψ, sin ψ, 0) is exact, and on a turn the position is its integral, tabulated once
on a fine grid and interpolated by cubic Hermite with those exact derivatives (error < 1e-7 m).
The mission starts on the first line, at cruise speed and working depth.

Frames: {W} NED, {B} x forward / y right / z down; R_WB = Rz(yaw)·Ry(pitch)·Rx(roll) with a small
roll/pitch wobble.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.integrate import cumulative_simpson
from scipy.interpolate import CubicHermiteSpline
from scipy.spatial.transform import Rotation

from semslam.sim.field_config import FieldTrajectoryConfig, SeabedConfig
from semslam.sim.trajectory import MotionModel, smoothstep

TURN_RAMP_SHARE = 0.2  # a half-turn's yaw rate ramps up over its first 20 % and down over its last 20 %


@functools.cache
def _unit_turn() -> tuple[CubicHermiteSpline, CubicHermiteSpline, float]:
    """The half-turn of unit arc length: its heading fraction G(u) (0 → 1; heading ψ₀ ± π·G) and
    its path F(u) = ∫₀ᵘ (cos πG, sin πG) (forward, lateral) as splines of u ∈ [0, 1], and its
    lateral offset F_y(1). The yaw rate ∝ G' is a plateau entered and left by quintic smoothsteps."""
    u = np.linspace(0.0, 1.0, 8193)
    f = TURN_RAMP_SHARE
    rate = np.minimum(smoothstep(u / f)[0], smoothstep((1.0 - u) / f)[0])
    rate /= 1.0 - f  # ∫ rate = 1: each ramp holds half of its share
    G = cumulative_simpson(rate, x=u, initial=0.0)
    G /= G[-1]  # exactly 1 at the end (a correction of ~1e-15)
    d = np.stack([np.cos(np.pi * G), np.sin(np.pi * G)], 1)
    F = np.stack([cumulative_simpson(d[:, k], x=u, initial=0.0) for k in range(2)], 1)
    return CubicHermiteSpline(u, G, rate), CubicHermiteSpline(u, F, d, axis=0), float(F[-1, 1])


class Lawnmower(MotionModel):
    """T_WB(t) of the field survey; ``t`` in seconds from the mission start."""

    def __init__(self, cfg: FieldTrajectoryConfig, seabed: SeabedConfig):
        self.cfg = cfg
        area_n, area_e = seabed.area_m
        cn, ce = cfg.center_m if cfg.center_m is not None else (0.0, 0.0)
        self.depth = seabed.depth_m - cfg.altitude_m
        self.v = cfg.speed_m_s
        L = cfg.line_length_m or area_e
        _, _, lateral = _unit_turn()
        self.turn_length = cfg.line_spacing_m / lateral
        # segments: (start arc length, length, start north, start east, start heading, turn sign or 0)
        segs = []
        s = 0.0
        for i in range(cfg.lines):
            north = cn + (i - (cfg.lines - 1) / 2) * cfg.line_spacing_m
            heading = np.pi / 2 if i % 2 == 0 else -np.pi / 2  # even lines east, odd lines west
            east0 = ce - L / 2 if i % 2 == 0 else ce + L / 2
            segs.append((s, L, north, east0, heading, 0))
            s += L
            if i + 1 < cfg.lines:
                # turn towards the north: left (yaw decreasing) when heading east, right when heading west
                segs.append((s, self.turn_length, north, east0 + np.sin(heading) * L, heading, -1 if i % 2 == 0 else 1))
                s += self.turn_length
        self.segments = np.array(segs, float)
        self.pattern_length = s
        self.T = cfg.duration_s if cfg.duration_s is not None else s / self.v

    @property
    def duration(self) -> float:
        return self.T

    def lines(self) -> list[dict]:
        """The survey lines: index, north (m), east from/to (m), heading (deg), time span (s)."""
        out = []
        for _k, (s0, length, n, e, psi, sign) in enumerate(self.segments):
            if sign != 0 or s0 / self.v >= self.T:
                continue
            t0, t1 = s0 / self.v, min((s0 + length) / self.v, self.T)  # the last line may be cut short
            out.append(
                {
                    "index": len(out),
                    "north_m": float(n),
                    "east_from_m": float(e),
                    "east_to_m": float(e + np.sin(psi) * self.v * (t1 - t0)),
                    "heading_deg": float(np.degrees(psi)),
                    "t_start_s": float(t0),
                    "t_end_s": float(t1),
                }
            )
        return out

    def _state(self, t):
        """Position (N×3), velocity (N×3) and heading ψ (N) at times t."""
        t = np.atleast_1d(np.asarray(t, float))
        s = self.v * t
        seg = self.segments
        k = np.clip(np.searchsorted(seg[:, 0], s, side="right") - 1, 0, len(seg) - 1)
        s0, length, n0, e0, psi0, sign = seg[k].T
        local = s - s0  # beyond the pattern, the last line simply continues
        u = np.where(sign != 0, local / np.where(sign != 0, length, 1.0), 0.0)
        G_of, F_of, _ = _unit_turn()
        u = np.clip(u, 0.0, 1.0)
        F = F_of(u)  # (forward, lateral) along the unit turn
        turning = sign != 0
        psi = np.where(turning, psi0 + sign * np.pi * G_of(u), psi0)
        fwd = np.where(turning, length * F[:, 0], local)
        lat = np.where(turning, sign * length * F[:, 1], 0.0)
        c0, s0_ = np.cos(psi0), np.sin(psi0)
        # local (forward, right) → (north, east): R(ψ₀) = [[cos, −sin], [sin, cos]]
        n = n0 + c0 * fwd - s0_ * lat
        e = e0 + s0_ * fwd + c0 * lat
        pos = np.stack([n, e, np.full_like(n, self.depth)], 1)
        vel = np.stack([self.v * np.cos(psi), self.v * np.sin(psi), np.zeros_like(n)], 1)
        return pos, vel, psi

    def position_velocity(self, t) -> tuple[np.ndarray, np.ndarray]:
        pos, vel, _ = self._state(t)
        return pos, vel

    def rotation(self, t) -> Rotation:
        """R_WB(t): heading along the path, with a small roll/pitch wobble."""
        t = np.atleast_1d(np.asarray(t, float))
        _, _, psi = self._state(t)
        A = np.deg2rad(self.cfg.roll_pitch_amplitude_deg)
        roll = A * np.sin(2 * np.pi * t / 7.3)
        pitch = A * np.sin(2 * np.pi * t / 11.1 + 0.7)
        return Rotation.from_euler("ZYX", np.stack([psi, pitch, roll], 1))
