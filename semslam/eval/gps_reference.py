"""GPS fixes as the reference of a mission: fixes held out of what the estimators see
(``--hold-out-gps last|every:N``) and each estimate's error at them.

* ``last``: the mission's last fix (after resurfacing, the one that closes the dive);
  ``every:N``: the N-th, 2N-th, ... fix. The fixes are those the reader keeps (a pass over the GPS
  and depth topics alone: fixes taken below ``reader.gps_max_depth_m`` are not fixes).
* The error at a held-out fix is between the fix and the estimated antenna position at its stamp
  (the pose interpolated between the estimate's poses, plus the lever arm t_BA turned by it),
  horizontal (north, east): the depth sensor, not the GPS, observes the depth, and a fix's height
  is its worst axis. The fix's own noise is in that error: ``gps_sigma_h_m`` says how much.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from semslam.errors import ConfigError
from semslam.estimation import Trajectory
from semslam.mission.measurements import GpsFix
from semslam.mission.mission import Mission
from semslam.results import PipelineResult

_EVERY = re.compile(r"every:(\d+)")
MAX_EXTRAPOLATION_S = 2.0  # a held-out fix this far past an estimate's ends is still compared (s)


@dataclass(frozen=True)
class HoldOut:
    """Which fixes to hold out: ``last`` or every ``n``-th."""

    every: int | None = None  # None: the last fix

    @classmethod
    def parse(cls, text: str) -> HoldOut:
        """``last`` or ``every:N`` (N ≥ 2: holding out every fix leaves the estimators none)."""
        text = text.strip()
        if text == "last":
            return cls()
        m = _EVERY.fullmatch(text)
        if m is None or int(m.group(1)) < 2:
            raise ConfigError(f"--hold-out-gps {text!r}: expected 'last' or 'every:N' with N >= 2")
        return cls(int(m.group(1)))

    def __str__(self) -> str:
        return "last" if self.every is None else f"every:{self.every}"

    def choose(self, fixes: list[GpsFix]) -> list[GpsFix]:
        if not fixes:
            return []
        if self.every is None:
            return [fixes[-1]]
        return fixes[self.every - 1 :: self.every]


def mission_fixes(mission: Mission) -> list[GpsFix]:
    """The GPS fixes of ``mission``, from a pass over its GPS and depth sensors only."""
    md = mission.metadata
    sensors = [s.name for s in (*md.sensors_of_kind("gps"), *md.sensors_of_kind("depth"))]
    return [m for m in mission.only(sensors) if isinstance(m, GpsFix)]


@dataclass
class GpsReference:
    """The held-out fixes of a mission and how they were chosen."""

    policy: HoldOut
    fixes: list[GpsFix]

    @classmethod
    def hold_out(cls, mission: Mission, policy: HoldOut) -> GpsReference:
        """The fixes ``policy`` holds out of ``mission``; none to hold out is a ConfigError."""
        fixes = mission_fixes(mission)
        held = policy.choose(fixes)
        if not held:
            raise ConfigError(
                f"--hold-out-gps {policy}: mission {mission.metadata.name} has no GPS fix to hold out "
                f"({len(fixes)} fixes)"
            )
        return cls(policy, held)

    def estimators_see(self, mission: Mission) -> Mission:
        """``mission`` without the held-out fixes."""
        held = {(f.sensor, f.stamp) for f in self.fixes}
        return mission.without(lambda m: isinstance(m, GpsFix) and (m.sensor, m.stamp) in held)

    def block(self) -> dict:
        """metrics.json's ``gps_reference``: the policy, the fixes held out, their horizontal σ."""
        return {
            "hold_out": str(self.policy),
            "n_fixes": len(self.fixes),
            "stamps": [int(f.stamp) for f in self.fixes],
            "gps_sigma_h_m": [float(np.sqrt(np.mean(np.diag(f.covariance)[:2]))) for f in self.fixes],
        }

    def errors(self, trajectory: Trajectory, levers: dict[str, np.ndarray]) -> np.ndarray:
        """Horizontal error (m) of ``trajectory`` at each held-out fix; ``levers``: t_BA by GPS sensor
        name. A fix up to :data:`MAX_EXTRAPOLATION_S` past the estimate's ends (the mission's last fix
        after its last keyframe) is reached with the velocity of the two end poses; further: NaN."""
        out = np.full(len(self.fixes), np.nan)
        s = np.asarray(trajectory.stamps, np.int64)
        if len(s) < 2:
            return out
        t = (s - s[0]) * 1e-9
        q = (np.array([f.stamp for f in self.fixes], np.int64) - s[0]) * 1e-9
        inside = (q >= -MAX_EXTRAPOLATION_S) & (q <= t[-1] + MAX_EXTRAPOLATION_S)
        if not inside.any():
            return out
        q = q[inside]
        P = trajectory.positions
        pos = np.stack([np.interp(q, t, P[:, k]) for k in range(3)], 1)
        after, before = q > t[-1], q < 0
        pos[after] += np.outer(q[after] - t[-1], (P[-1] - P[-2]) / (t[-1] - t[-2]))
        pos[before] += np.outer(q[before], (P[1] - P[0]) / t[1])
        R = Slerp(t, Rotation.from_quat(trajectory.orientations))(np.clip(q, 0.0, t[-1])).as_matrix()
        fixes = [f for f, ok in zip(self.fixes, inside) if ok]
        antenna = pos + np.einsum("nij,nj->ni", R, np.array([levers[f.sensor] for f in fixes]))
        measured = np.array([f.position for f in fixes])
        out[inside] = np.linalg.norm((antenna - measured)[:, :2], axis=1)
        return out

    def metrics(self, trajectory: Trajectory, levers: dict[str, np.ndarray]) -> dict:
        """The per-estimator keys: RMS, max and last of the horizontal errors at the held-out fixes
        (None when the estimate spans none of them)."""
        e = self.errors(trajectory, levers)
        ok = e[np.isfinite(e)]
        if not len(ok):
            return {"gps_error_rmse_m": None, "gps_error_max_m": None, "gps_error_last_m": None, "gps_errors_m": []}
        return {
            "gps_error_rmse_m": float(np.sqrt(np.mean(ok**2))),
            "gps_error_max_m": float(ok.max()),
            "gps_error_last_m": float(ok[-1]),
            "gps_errors_m": [None if not np.isfinite(x) else float(x) for x in e],
        }


def add_gps_reference(metrics: dict, reference: GpsReference | None, pipeline: PipelineResult, metadata) -> dict:
    """metrics.json's ``reference`` ("gps" with held-out fixes, else "ground_truth" when the run had
    it, else None), ``gps_reference`` and, per estimator, the errors at the held-out fixes."""
    results = pipeline.results
    metrics["reference"] = "gps" if reference is not None else ("ground_truth" if pipeline.truth is not None else None)
    metrics["gps_reference"] = reference.block() if reference is not None else None
    if reference is None:
        return metrics
    levers = {s.name: s.T_BS[:3, 3] for s in metadata.sensors_of_kind("gps")}
    for name, result in results.items():
        for key in (name, f"{name}_online"):
            if key not in metrics["estimators"]:
                continue
            traj = result.trajectory if key == name else result.online_trajectory
            metrics["estimators"][key].update(reference.metrics(traj, levers))
    return metrics
