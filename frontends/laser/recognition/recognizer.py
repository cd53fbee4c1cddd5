"""The object recogniser: a segmented object cloud → its class likelihood vector P(Z | X).

A segment (sensor frame, the scanner at the origin) is described (ESF by default; VFH or CVFH on
request), matched against the view database (chi-square nearest neighbour, or the RBF SVM), and
the recognised class z becomes the likelihood vector P(Z = z | X = x) over every class x — column
z of the recogniser's confusion matrix on held-out synthetic views (the paper's SYN stage),
row-normalised and smoothed (:class:`semslam.semantics.ConfusionModel`). Fusing those vectors per
landmark, with the pipe connectivity, is :class:`semslam.semantics.ClassFusion`'s job, so
``classify`` ignores the connectivity unless ``apply_connectivity`` is set.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from frontends.laser.recognition.cvfh import cvfh
from frontends.laser.recognition.esf import esf, esf_many
from frontends.laser.recognition.matching import (
    Chi2Index,
    chi2_distances,
    make_svm,
    principal_extents,
    set_distances,
    size_distances,
    svm_features,
)
from frontends.laser.recognition.pose import ModelSurface, PoseEstimate, estimate_pose
from frontends.laser.recognition.vfh import vfh
from frontends.laser.recognition.views import (
    RecognitionError,
    ViewDatabase,
    ViewParams,
    default_cache_dir,
    random_directions,
    render_views,
    write_atomic,
)
from semslam.semantics.connectivity import ConnectivityTable, compatible_configurations
from semslam.semantics.likelihood import ConfusionModel
from semslam.semantics.metrics import confusion_matrix

DESCRIPTORS = ("esf", "vfh", "cvfh")
METHODS = ("nn", "svm")


@dataclass(frozen=True)
class Recognition:
    """The answer for one segment: recognised class, best view (database index) and its distance."""

    cls: str
    view: int
    distance: float


@dataclass(frozen=True)
class HeldOutParams:
    """Held-out synthetic views for the SYN confusion matrix: random viewpoints (not the
    database's Fibonacci ones), random distances and rolls, fresh noise."""

    n_per_model: int = 20
    distance_range_m: tuple[float, float] = (1.0, 4.0)
    range_sigma_m: float = 0.005
    seed: int = 12345


def held_out_views(
    models: dict, params: HeldOutParams, angular_resolution_rad: float, min_points: int = 30
) -> tuple[list[np.ndarray], list[str]]:
    """Clouds (camera frame) and true classes of held-out views of ``models`` (name → (cls, mesh, ports))."""
    rng = np.random.default_rng(params.seed)
    clouds, labels = [], []
    for _name, (cls, mesh, _ports) in models.items():
        n = params.n_per_model
        cs, _ = render_views(
            mesh, random_directions(n, rng), distance_m=rng.uniform(*params.distance_range_m, size=n),
            angular_resolution_rad=angular_resolution_rad, range_sigma_m=params.range_sigma_m, rng=rng,
            rolls_rad=rng.uniform(0, 2 * np.pi, size=n),
        )  # fmt: skip
        for c in cs:
            if len(c) >= min_points:
                clouds.append(c)
                labels.append(cls)
    return clouds, labels


def _segment(cloud: np.ndarray) -> np.ndarray:
    """A segment as float64 N×3, at least 10 points (ValueError otherwise)."""
    pts = np.asarray(cloud, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 10:
        raise ValueError(f"a segment needs at least 10 points (N×3), got shape {pts.shape}")
    return pts


class Recognizer:
    """Recognises object segments against a :class:`ViewDatabase`.

    ``confusion`` (true × recognised counts over ``classes``) is the SYN confusion matrix that
    turns a recognition into P(Z | X); without it, a generic one is assumed (``default_accuracy``
    on the diagonal, the rest spread evenly) until :meth:`calibrate` measures it.
    """

    def __init__(
        self,
        database: ViewDatabase,
        *,
        descriptor: str = "esf",
        method: str = "nn",
        confusion: np.ndarray | None = None,
        default_accuracy: float = 0.8,
        apply_connectivity: bool = False,
        size_weight: float = 0.2,
        esf_samples: int = 20000,
        seed: int = 0,
    ):
        if descriptor not in DESCRIPTORS:
            raise RecognitionError(f"unknown descriptor {descriptor!r} (one of {', '.join(DESCRIPTORS)})")
        if method not in METHODS:
            raise RecognitionError(f"unknown matching method {method!r} (one of {', '.join(METHODS)})")
        if method == "svm" and descriptor == "cvfh":
            raise RecognitionError("the SVM needs one descriptor per view: use esf or vfh with --method svm")
        self.db = database
        self.descriptor = descriptor
        self.method = method
        self.seed = seed
        self.esf_samples = int(esf_samples)
        self.classes = database.classes
        self.apply_connectivity = apply_connectivity
        self.size_weight = float(size_weight)
        self._labels = database.labels
        self._features = database.features(descriptor)
        self._index = Chi2Index(self._features) if descriptor != "cvfh" else None
        self._extents = database.features("extent")
        self._log_extents = np.log(self._extents)
        if method == "svm":
            ext = self._extents if self.size_weight > 0 else None
            self._svm = make_svm(n_size=0 if ext is None else 3).fit(svm_features(self._features, ext), self._labels)
        self.connectivity = ConnectivityTable(self._compatibility())
        k = len(self.classes)
        # Whether ``confusion`` was measured (SYN) rather than the generic assumption below.
        self.confusion_measured = confusion is not None
        if confusion is None:
            confusion = np.full((k, k), (1 - default_accuracy) / max(k - 1, 1)) * 100
            np.fill_diagonal(confusion, default_accuracy * 100)
        self.set_confusion(confusion)
        self._surfaces: dict[int, ModelSurface] = {}

    def _compatibility(self) -> dict[str, frozenset[int]]:
        """Connectivity table from the models' ports where known (the default table otherwise)."""
        table = dict(ConnectivityTable().compatibility)
        for m in self.db.models:
            if m.ports:
                table[m.cls] = table.get(m.cls, frozenset()) | compatible_configurations([d for _, d in m.ports])
        return table

    def set_confusion(self, confusion: np.ndarray) -> None:
        self.confusion = np.asarray(confusion, dtype=np.float64)
        self.model = ConfusionModel(self.confusion, self.classes)

    # ------------------------------------------------------------------------------------------

    def describe(self, cloud: np.ndarray) -> np.ndarray:
        """The configured descriptor of a segment in its sensor frame (viewpoint at the origin)."""
        if self.descriptor == "esf":
            return esf(cloud, n_samples=self.esf_samples, seed=self.seed)
        if self.descriptor == "vfh":
            return vfh(cloud)
        return cvfh(cloud)

    def recognise(self, cloud: np.ndarray) -> Recognition:
        """The recognised class of an N×3 segment (sensor frame, metres) and its nearest view."""
        pts = _segment(cloud)
        return self._match(pts, self.describe(pts))

    def _match(self, pts: np.ndarray, q: np.ndarray) -> Recognition:
        """The recognition of a segment (N×3 float64) whose descriptor is ``q``."""
        ext = principal_extents(pts)
        if self.method == "nn" and self._index is not None and self.size_weight > 0:
            size_d = np.abs(np.log(ext) - self._log_extents).sum(axis=1)  # size_distances, logs kept
            view, dist = self._nearest_view(q, self.size_weight * size_d)
            return Recognition(str(self._labels[view]), view, dist)
        d = set_distances(q, self._features) if self.descriptor == "cvfh" else self._index.distances(q)
        if self.size_weight > 0:
            d = d + self.size_weight * size_distances(ext, self._extents)
        view = int(np.argmin(d))
        if self.method == "nn":
            return Recognition(str(self._labels[view]), view, float(d[view]))
        cls = str(self._svm.predict(svm_features(q, ext if self.size_weight > 0 else None))[0])
        in_cls = np.flatnonzero(self._labels == cls)
        view = int(in_cls[np.argmin(d[in_cls])])
        return Recognition(cls, view, float(d[view]))

    def _nearest_view(self, q: np.ndarray, size_d: np.ndarray, head: int = 48) -> tuple[int, float]:
        """The view minimising chi²(q, view) + ``size_d`` (its size term), exactly, computing chi²
        only where it can win: first for the ``head`` views nearest in size, then for the views
        whose size term alone is below the best total so far (chi² ≥ 0 bounds the others out)."""
        order = np.argsort(size_d)
        rows = order[:head]
        d = self._index.distances(q, rows) + size_d[rows]
        best = int(np.argmin(d))
        view, dist = int(rows[best]), float(d[best])
        rest = order[head:]
        rest = rest[size_d[rest] < dist]
        if len(rest):
            d = self._index.distances(q, rest) + size_d[rest]
            best = int(np.argmin(d))
            if d[best] < dist:
                view, dist = int(rest[best]), float(d[best])
        return view, dist

    def classify(self, cloud: np.ndarray, connectivity=None) -> dict[str, float]:
        """P(Z | X): the likelihood of this segment's recognition under every class X.

        ``cloud``: N×3 (float32 or float64, sensor frame, metres). A segment too small or too
        degenerate to describe (fewer than 10 points, all collinear) gets the uninformative
        likelihood (1 for every class). ``connectivity`` (a
        :class:`semslam.observations.Connectivity`, a configuration 1–4, or None) only matters with
        ``apply_connectivity``; otherwise the fusion applies it.
        """
        try:
            lik = self.model.likelihood(self.recognise(cloud).cls)
        except ValueError:  # too few or degenerate points: no evidence, not a failure of the scan
            lik = {c: 1.0 for c in self.classes}
        return self._with_connectivity(lik, connectivity)

    def classify_many(
        self, clouds: Sequence[np.ndarray], connectivities: Sequence | None = None
    ) -> list[dict[str, float]]:
        """``classify`` of every segment of a scan (the same likelihoods), their ESF descriptors
        computed together (:func:`esf_many`: one pass of numpy calls for all the segments)."""
        conns = list(connectivities) if connectivities is not None else [None] * len(clouds)
        if self.descriptor != "esf":
            return [self.classify(c, k) for c, k in zip(clouds, conns)]
        segments: list[np.ndarray | None] = []
        for cloud in clouds:
            try:
                segments.append(_segment(cloud))
            except ValueError:
                segments.append(None)
        valid = [k for k, pts in enumerate(segments) if pts is not None]
        described = esf_many([segments[k] for k in valid], n_samples=self.esf_samples, seed=self.seed)
        q_of = dict(zip(valid, described))
        out = []
        for k, conn in enumerate(conns):
            q = q_of.get(k)
            if q is None:  # too few or degenerate points: no evidence (as ``classify``)
                lik = {c: 1.0 for c in self.classes}
            else:
                lik = self.model.likelihood(self._match(segments[k], q).cls)
            out.append(self._with_connectivity(lik, conn))
        return out

    def _with_connectivity(self, lik: dict[str, float], connectivity) -> dict[str, float]:
        """The likelihood masked by the connectivity's compatible classes, with ``apply_connectivity``."""
        if self.apply_connectivity and connectivity is not None:
            conf = getattr(connectivity, "configuration", connectivity)
            if conf is not None:
                mask = self.connectivity.mask(self.classes, [int(conf)])
                if any(mask[i] > 0 for i in range(len(mask))):
                    lik = {c: v * m for (c, v), m in zip(lik.items(), mask)}
        return lik

    def pose(
        self, cloud: np.ndarray, recognition: Recognition | None = None, n_views: int = 12
    ) -> tuple[str, PoseEstimate]:
        """Name of the recognised model and its pose T_SM: ICP started from the camera poses of
        the ``n_views`` views of that model nearest to the segment's descriptor."""
        pts = np.asarray(cloud, dtype=np.float64)
        rec = recognition or self.recognise(pts)
        mi = int(self.db.view_model[rec.view])
        if mi not in self._surfaces:
            self._surfaces[mi] = ModelSurface(self._mesh_of(mi), seed=self.seed)
        views = np.flatnonzero(self.db.view_model == mi)
        q = self.describe(pts)
        d = (
            set_distances(q, [self._features[v] for v in views])
            if self.descriptor == "cvfh"
            else chi2_distances(q, self._features[views])
        )
        best = views[np.argsort(d)[:n_views]]
        return self.db.models[mi].name, estimate_pose(pts, self._surfaces[mi], self.db.T_CM[best])

    def _mesh_of(self, model_index: int):
        mv = self.db.models[model_index]
        meshes = self.db.meshes
        if mv.name not in meshes:
            raise RecognitionError(f"no mesh for model {mv.name!r}: pose needs the database's meshes")
        return meshes[mv.name]

    # ------------------------------------------------------------------------------------------

    def evaluate(self, clouds: Sequence[np.ndarray], labels: Sequence[str]) -> np.ndarray:
        """Confusion matrix (true × recognised, counts over ``classes``) on labelled segments."""
        pred = [self.recognise(c).cls for c in clouds]
        return confusion_matrix(list(labels), pred, self.classes)

    def calibrate(
        self, models: dict, params: HeldOutParams = HeldOutParams(), angular_resolution_rad: float | None = None
    ) -> np.ndarray:
        """Measure the SYN confusion on held-out views of ``models`` and use it as P(Z | X)."""
        res = angular_resolution_rad or ViewParams().angular_resolution_rad
        clouds, labels = held_out_views(models, params, res)
        conf = self.evaluate(clouds, labels)
        self.set_confusion(conf)
        self.confusion_measured = True
        return conf


def default_recognizer(
    *,
    descriptor: str = "esf",
    method: str = "nn",
    size_weight: float = 0.2,
    esf_samples: int = 20000,
    params: ViewParams = ViewParams(),
    held_out: HeldOutParams = HeldOutParams(),
    cache_dir: str | Path | None = None,
    models: dict | None = None,
    progress: bool = False,
) -> Recognizer:
    """A recogniser over the built-in CAD library (plus registered user models), calibrated on
    held-out synthetic views; the views and the SYN confusion are cached (by model content and
    parameters), so only the first call pays for rendering."""
    from frontends.laser.recognition.views import _read_mesh, builtin_models, load_database, registered_models

    models = builtin_models() if models is None else dict(models)
    for name, entry in registered_models(cache_dir).items():
        mesh = _read_mesh(Path(entry["path"]), entry.get("scale", 1.0))
        models[name] = (entry["cls"], mesh, [(np.asarray(p), np.asarray(d)) for p, d in entry.get("ports", [])])
    db = load_database(models, params, cache_dir=cache_dir, include_user_models=False, progress=progress)
    rec = Recognizer(db, descriptor=descriptor, method=method, size_weight=size_weight, esf_samples=esf_samples)

    tag = [sorted(m.key for m in db.models), descriptor, method, size_weight, repr(held_out)]
    if descriptor == "esf" and esf_samples != 20000:  # (keys of the 20000-sample default unchanged)
        tag.append(esf_samples)
    key = hashlib.sha256(json.dumps(tag).encode()).hexdigest()[:16]
    path = Path(cache_dir or default_cache_dir()) / "syn" / f"confusion-{key}.json"
    if path.is_file():
        data = json.loads(path.read_text())
        if data.get("classes") == rec.classes:
            rec.set_confusion(np.array(data["confusion"]))
            rec.confusion_measured = True
            return rec
    conf = rec.calibrate(models, held_out, params.angular_resolution_rad)
    write_atomic(path, json.dumps({"classes": rec.classes, "confusion": conf.tolist()}))
    return rec
