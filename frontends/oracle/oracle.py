"""The oracle front-end: at each laser scan, every ground-truth object, pipe (and structure) in the
laser's view becomes a noisy observation in the sensor frame, with its covariance and ``truth_id``.

It consumes ``PointCloud`` (only to know when and with which sensor the laser scans) and
``GroundTruthPose`` (to know where the vehicle truly is). Misses, false positives and
classification errors are drawn from a seeded generator, so a run is reproducible.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from frontends.oracle.config import OracleConfig
from semslam.errors import ConfigError, validated
from semslam.estimation import EstimateView
from semslam.mission.measurements import GroundTruthPose, Measurement, PointCloud
from semslam.mission.mission import MissionMetadata
from semslam.observations import Connectivity, LineObservation, Observation, PointObservation, StructureObservation
from semslam.registry import Frontend


class OracleFrontend(Frontend):
    config_model: ClassVar[type] = OracleConfig  # its section of the configuration, frontends.<name>
    name: ClassVar[str] = "oracle"
    consumes: ClassVar[tuple[type[Measurement], ...]] = (PointCloud, GroundTruthPose)
    uses_view: ClassVar[bool] = False  # ground truth only: it may run in a process of its own

    def __init__(self, metadata: MissionMetadata, config: dict | None = None):
        self.config = validated(OracleConfig, config, "frontends.oracle")
        if metadata.ground_truth is None:
            raise ConfigError(f"front-end 'oracle' needs a mission with ground truth ({metadata.name} has none)")
        self.metadata = metadata
        gt = metadata.ground_truth
        self.classes = tuple(gt.classes) or tuple(sorted({o.cls for o in gt.objects}))
        self.rng = np.random.default_rng(self.config.seed)
        self._obj_pos = gt.object_positions()
        self._pipe_by_id = {p.id: p for p in gt.pipes}
        axis = np.asarray(self.config.view_axis, float)
        self._axis = axis / np.linalg.norm(axis)
        self._cos_fov = np.cos(np.radians(self.config.fov_half_angle_deg))
        self._gt: list[GroundTruthPose] = []  # the last two true poses, for interpolation

    # ------------------------------------------------------------------------------------------
    def process(self, measurement: Measurement, view: EstimateView | None = None) -> list[Observation]:
        if isinstance(measurement, GroundTruthPose):
            self._gt = (self._gt + [measurement])[-2:]
            return []
        if not isinstance(measurement, PointCloud) or not self._gt:
            return []
        T_WS = self._true_pose(measurement.stamp) @ self.metadata.extrinsic(measurement.sensor)
        R_WS, t_WS = T_WS[:3, :3], T_WS[:3, 3]
        obs: list[Observation] = []
        obs += self._objects(measurement, R_WS, t_WS)
        obs += self._pipes(measurement, R_WS, t_WS)
        if self.config.structures:
            obs += self._structures(measurement, T_WS)
        obs += self._false_positives(measurement, len(obs))
        return obs

    # ------------------------------------------------------------------------------------------
    def _true_pose(self, stamp: int) -> np.ndarray:
        """T_WB at ``stamp``, interpolated (or extrapolated) from the last two true poses."""
        if len(self._gt) == 1 or self._gt[-1].stamp == self._gt[0].stamp:
            return self._gt[-1].matrix()
        a, b = self._gt
        s = (stamp - a.stamp) / (b.stamp - a.stamp)
        T = np.eye(4)
        T[:3, 3] = a.position + s * (b.position - a.position)
        rots = Rotation.from_quat([a.orientation, b.orientation])
        if 0.0 <= s <= 1.0:
            T[:3, :3] = Slerp([0.0, 1.0], rots)([s]).as_matrix()[0]
        else:
            rel = rots[0].inv() * rots[1]
            T[:3, :3] = (rots[0] * Rotation.from_rotvec(rel.as_rotvec() * s)).as_matrix()
        return T

    def _visible(self, p_S: np.ndarray) -> np.ndarray:
        """Boolean mask of sensor-frame points (N,3) inside the visibility cone."""
        r = np.linalg.norm(p_S, axis=1)
        cosang = (p_S @ self._axis) / np.maximum(r, 1e-12)
        return (r >= self.config.min_range_m) & (r <= self.config.max_range_m) & (cosang >= self._cos_fov)

    def _kept(self, n: int) -> np.ndarray:
        return self.rng.random(n) >= self.config.miss_rate

    def _likelihood(self, true_cls: str | None) -> dict[str, float]:
        """Confusion column P(Z = detected | X = c): accuracy on the detected class, the rest shared."""
        k = len(self.classes)
        if k == 0:
            return {}
        acc = self.config.classification_accuracy
        if true_cls in self.classes and self.rng.random() < acc:
            detected = true_cls
        else:
            others = [c for c in self.classes if c != true_cls] or list(self.classes)
            detected = others[self.rng.integers(len(others))]
        off = (1.0 - acc) / (k - 1) if k > 1 else 0.0
        return {c: (acc if c == detected else off) for c in self.classes}

    def _point_noise(self, rng_m: float) -> tuple[np.ndarray, np.ndarray]:
        s = self.config.point_sigma_m + self.config.point_sigma_per_m * rng_m
        cov = np.eye(3) * max(s, 1e-4) ** 2
        return self.rng.normal(size=3) * s, cov

    def _objects(self, m: PointCloud, R_WS, t_WS) -> list[Observation]:
        gt = self.metadata.ground_truth
        if not gt.objects:
            return []
        p_S = (self._obj_pos - t_WS) @ R_WS
        vis = np.flatnonzero(self._visible(p_S) & self._kept(len(p_S)))
        out = []
        for i in vis:
            o = gt.objects[i]
            noise, cov = self._point_noise(float(np.linalg.norm(p_S[i])))
            out.append(
                PointObservation(
                    stamp=m.stamp,
                    sensor=m.sensor,
                    position=p_S[i] + noise,
                    covariance=cov,
                    class_likelihood=self._likelihood(o.cls),
                    connectivity=self._connectivity(o, R_WS),
                    truth_id=o.id,
                )
            )
        return out

    def _connectivity(self, o, R_WS) -> Connectivity:
        dirs = []
        c = np.asarray(o.position)
        for pid in o.pipes:
            p = self._pipe_by_id.get(pid)
            if p is None:
                continue
            a, b = np.asarray(p.p), np.asarray(p.q)
            far = b if np.linalg.norm(b - c) >= np.linalg.norm(a - c) else a
            near = a if far is b else b
            d = far - near
            if np.linalg.norm(d) > 0:
                dirs.append(R_WS.T @ (d / np.linalg.norm(d)))
        n = len(dirs)
        if n == 0:
            conf = None
        elif n == 1:
            conf = 1
        elif n == 2:
            conf = 2 if abs(float(dirs[0] @ dirs[1])) > 0.9 else 3
        else:
            conf = 4
        return Connectivity(n_pipes=n, configuration=conf, directions=tuple(tuple(map(float, d)) for d in dirs))

    def _pipes(self, m: PointCloud, R_WS, t_WS) -> list[Observation]:
        cfg = self.config
        out = []
        for pipe in self.metadata.ground_truth.pipes:
            if not self._kept(1)[0]:
                continue
            a, b = np.asarray(pipe.p), np.asarray(pipe.q)
            length = float(np.linalg.norm(b - a))
            n = max(2, int(np.ceil(length * cfg.pipe_samples_per_m)) + 1)
            s = np.linspace(0.0, 1.0, n)
            pts_S = (a + s[:, None] * (b - a) - t_WS) @ R_WS
            vis = np.flatnonzero(self._visible(pts_S))
            if len(vis) < 2 or (s[vis[-1]] - s[vis[0]]) * length < cfg.min_pipe_length_m:
                continue
            p_S, q_S = pts_S[vis[0]], pts_S[vis[-1]]
            out.append(self._line_obs(m, p_S, q_S, pipe.id, pipe.radius))
        return out

    def _line_obs(self, m, p_S, q_S, truth_id, radius) -> LineObservation:
        """Endpoints with anisotropic noise: line_sigma perpendicular, line_along_sigma along the axis."""
        cfg = self.config
        d = (q_S - p_S) / np.linalg.norm(q_S - p_S)
        cov1 = (np.eye(3) - np.outer(d, d)) * cfg.line_sigma_m**2 + np.outer(d, d) * cfg.line_along_sigma_m**2
        cov1 += np.eye(3) * 1e-8
        L = np.linalg.cholesky(cov1)
        p_n = p_S + L @ self.rng.normal(size=3)
        q_n = q_S + L @ self.rng.normal(size=3)
        cov = np.zeros((6, 6))
        cov[:3, :3] = cov1
        cov[3:, 3:] = cov1
        return LineObservation(
            stamp=m.stamp, sensor=m.sensor, p=p_n, q=q_n, covariance=cov, radius=radius, truth_id=truth_id
        )

    def _structures(self, m: PointCloud, T_WS) -> list[Observation]:
        cfg = self.config
        out = []
        for st in self.metadata.ground_truth.structures:
            T_SM = np.linalg.inv(T_WS) @ st.matrix()
            if not (self._visible(T_SM[None, :3, 3])[0] and self._kept(1)[0]):
                continue
            xi_r = self.rng.normal(size=3) * cfg.structure_sigma_rad
            xi_t = self.rng.normal(size=3) * cfg.structure_sigma_m
            N = np.eye(4)
            N[:3, :3] = Rotation.from_rotvec(xi_r).as_matrix()
            N[:3, 3] = xi_t
            cov = np.diag([max(cfg.structure_sigma_rad, 1e-4) ** 2] * 3 + [max(cfg.structure_sigma_m, 1e-4) ** 2] * 3)
            out.append(
                StructureObservation(
                    stamp=m.stamp, sensor=m.sensor, model=st.model, pose=T_SM @ N, covariance=cov, truth_id=st.id
                )
            )
        return out

    def _random_in_view(self) -> np.ndarray:
        """A uniformly random direction in the cone at a uniform range."""
        cfg = self.config
        cos_t = self.rng.uniform(self._cos_fov, 1.0)
        phi = self.rng.uniform(0, 2 * np.pi)
        sin_t = np.sqrt(1 - cos_t**2)
        a = self._axis
        helper = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
        u = np.cross(a, helper)
        u /= np.linalg.norm(u)
        v = np.cross(a, u)
        d = cos_t * a + sin_t * (np.cos(phi) * u + np.sin(phi) * v)
        return d * self.rng.uniform(max(cfg.min_range_m, 0.3), cfg.max_range_m)

    def _false_positives(self, m: PointCloud, n_true: int) -> list[Observation]:
        rate = self.config.false_positive_rate
        if rate <= 0:
            return []
        n_fp = self.rng.poisson(rate * max(n_true, 1))
        out = []
        for _ in range(n_fp):
            if self.rng.random() < 0.75 or not self.metadata.ground_truth.pipes:
                p = self._random_in_view()
                noise, cov = self._point_noise(float(np.linalg.norm(p)))
                out.append(
                    PointObservation(
                        stamp=m.stamp,
                        sensor=m.sensor,
                        position=p + noise,
                        covariance=cov,
                        class_likelihood=self._likelihood(None),
                    )
                )
            else:
                p = self._random_in_view()
                d = self.rng.normal(size=3)
                d /= np.linalg.norm(d)
                out.append(self._line_obs(m, p, p + d * self.rng.uniform(0.3, 1.0), None, None))
        return out
