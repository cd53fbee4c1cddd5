"""Object recognition: virtual scanner, view cache, user models, matching, classification, ICP pose."""

from __future__ import annotations

import json

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from frontends.laser.recognition.matching import (
    ChiSquareNN,
    chi2_distances,
    leave_one_out,
    principal_extents,
    set_distances,
)
from frontends.laser.recognition.recognizer import HeldOutParams, Recognizer, held_out_views
from frontends.laser.recognition.views import (
    RecognitionError,
    ViewParams,
    VirtualScanner,
    add_model,
    build_model_views,
    load_database,
    look_at,
    registered_models,
    remove_model,
)
from semslam.errors import SemslamError

RES = ViewParams().angular_resolution_rad


def _box(x, y, z, at=(0.0, 0.0, 0.0)):
    m = o3d.geometry.TriangleMesh.create_box(x, y, z)
    m.translate(np.asarray(at) - np.array([x, y, z]) / 2)
    return m


def shapes() -> dict:
    """Four primitive 'classes' of similar size (so that shape, not size, tells them apart)."""
    cyl = o3d.geometry.TriangleMesh.create_cylinder(radius=0.07, height=0.28, resolution=32)
    sph = o3d.geometry.TriangleMesh.create_sphere(radius=0.12, resolution=24)
    tor = o3d.geometry.TriangleMesh.create_torus(torus_radius=0.1, tube_radius=0.035)
    ell = _box(0.26, 0.08, 0.08) + _box(0.08, 0.2, 0.08, at=(0.09, 0.14, 0.0))  # an L of two bars
    return {"cyl": ("Cylinder", cyl, []), "sph": ("Sphere", sph, []), "tor": ("Torus", tor, []), "ell": ("L", ell, [])}


def _view_cache(request):
    """A view cache kept across test runs (pytest's cache dir): views are keyed by model content and
    parameters, so reuse is exact; the cache itself is tested on fresh directories below. Without
    pytest's cache (-p no:cacheprovider) one folder for the session, as the cache dir is on a clean
    clone: the database's views are not built twice."""
    cache = getattr(request.config, "cache", None)  # absent under -p no:cacheprovider
    if cache is None:
        folder = request.getfixturevalue("tmp_path_factory").getbasetemp() / "semslam-views"
        folder.mkdir(exist_ok=True)
        return folder
    return cache.mkdir("semslam-views")


@pytest.fixture(scope="module")
def database(request):
    cache = _view_cache(request)
    params = ViewParams(n_views=12, distances_m=(1.2, 1.9))
    return load_database(shapes(), params, cache_dir=cache, include_user_models=False), cache


def test_virtual_scanner_samples_the_visible_surface_with_range_noise():
    r, dist, sigma = 0.1, 1.5, 0.005
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=r, resolution=40)
    scanner = VirtualScanner(mesh)
    T_MC = look_at(np.array([dist, 0.0, 0.0]), np.zeros(3))
    pts_c = scanner.scan(T_MC, RES, sigma, np.random.default_rng(0))
    # Points are in the camera frame: in front of it (z > 0), on the near cap of the sphere.
    assert np.all(pts_c[:, 2] > dist - r - 5 * sigma) and np.all(pts_c[:, 2] < dist + 5 * sigma)
    pts_m = pts_c @ T_MC[:3, :3].T + T_MC[:3, 3]
    radial = np.linalg.norm(pts_m, axis=1) - r
    assert abs(np.mean(radial)) < 0.002
    assert np.std(radial) == pytest.approx(sigma, rel=0.35)  # range noise seen across the surface
    # One ray per RES × RES cell of the sphere's silhouette.
    expected = np.pi * np.arcsin(r / dist) ** 2 / RES**2
    assert len(pts_c) == pytest.approx(expected, rel=0.1)


def test_view_cache_is_keyed_by_content(tmp_path):
    cls, mesh, _ = shapes()["cyl"]
    params = ViewParams(n_views=4, distances_m=(1.5,))
    a = build_model_views("cyl", cls, mesh, params, cache_dir=tmp_path)
    files = list((tmp_path / "views").glob("*.npz"))
    assert len(files) == 1
    b = build_model_views("cyl", cls, mesh, params, cache_dir=tmp_path)  # from the cache
    np.testing.assert_array_equal(a.descriptors.esf, b.descriptors.esf)
    assert all(np.array_equal(x, y) for x, y in zip(a.descriptors.cvfh, b.descriptors.cvfh))
    np.testing.assert_array_equal(a.T_CM, b.T_CM)
    bigger = o3d.geometry.TriangleMesh(mesh).scale(1.1, center=np.zeros(3))
    c = build_model_views("cyl", cls, bigger, params, cache_dir=tmp_path)
    assert c.key != a.key and len(list((tmp_path / "views").glob("*.npz"))) == 2
    d = build_model_views(
        "cyl", cls, mesh, ViewParams(n_views=4, distances_m=(1.5,), range_sigma_m=0.002), cache_dir=tmp_path
    )
    assert d.key != a.key
    files[0].write_bytes(b"garbage")
    with pytest.raises(RecognitionError, match="corrupt view cache"):
        build_model_views("cyl", cls, mesh, params, cache_dir=tmp_path)


def test_add_user_model_makes_it_recognisable(tmp_path, database):
    db, _ = database
    stl = tmp_path / "my_valve.stl"
    mesh = o3d.geometry.TriangleMesh.create_cone(radius=0.1, height=0.25, resolution=32)
    mesh.compute_triangle_normals()
    assert o3d.io.write_triangle_mesh(str(stl), mesh)
    cache = tmp_path / "cache"
    params = ViewParams(n_views=12, distances_m=(1.2, 1.9))
    mv = add_model(stl, "Cone", params=params, cache_dir=cache, ports=[((0, 0, 0), (0, 0, -1))])
    assert mv.cls == "Cone" and len(mv.T_CM) > 10
    reg = registered_models(cache)
    assert reg["my_valve"]["cls"] == "Cone" and reg["my_valve"]["path"] == str(stl.resolve())
    db2 = load_database({}, params, cache_dir=cache)
    assert db2.classes == ["Cone"] and "my_valve" in db2.meshes
    # The user model joins the primitive database and is recognised from a new viewpoint.
    both = type(db)(db.models + db2.models, {**db.meshes, **db2.meshes})
    rec = Recognizer(both, size_weight=0.0)
    clouds, labels = held_out_views({"my_valve": ("Cone", mesh, [])}, HeldOutParams(n_per_model=4, seed=3), RES)
    assert sum(rec.recognise(c).cls == "Cone" for c in clouds) >= 3
    assert rec.connectivity.compatibility["Cone"] == frozenset({1})  # from its single port
    assert remove_model("my_valve", cache) and registered_models(cache) == {}


@pytest.mark.parametrize(
    "bad, match",
    [("missing.stl", "not found"), ("model.step", "unsupported CAD format"), ("empty.ply", "no triangles")],
)
def test_add_model_user_errors_are_one_line(tmp_path, bad, match):
    path = tmp_path / bad
    if bad != "missing.stl":
        path.write_text("ply\nformat ascii 1.0\nelement vertex 0\nend_header\n" if bad.endswith(".ply") else "x")
    with pytest.raises(SemslamError, match=match) as exc:
        add_model(path, "Valve", cache_dir=tmp_path / "c")
    assert "\n" not in str(exc.value)
    with pytest.raises(RecognitionError, match="class name"):
        add_model(path, " ", cache_dir=tmp_path / "c")


def test_chi2_and_set_distances():
    rng = np.random.default_rng(0)
    X = rng.random((5, 8))
    q = rng.random(8)
    d = chi2_distances(q, X)
    manual = [0.5 * np.sum((q - x) ** 2 / (q + x)) for x in X]
    np.testing.assert_allclose(d, manual)
    assert chi2_distances(X[2], X)[2] == 0.0
    sets = [X[:2], X[2:3], X[3:]]
    np.testing.assert_allclose(set_distances(np.stack([q, X[4]]), sets), [min(d[:2]), d[2], 0.0])
    e = principal_extents(rng.normal(size=(5000, 3)) * [0.3, 0.1, 0.02])
    np.testing.assert_allclose(e, [0.3, 0.1, 0.02], rtol=0.05)


def test_leave_one_out_nearest_neighbour():
    rng = np.random.default_rng(1)
    X = rng.random((30, 6))
    y = rng.choice(["a", "b", "c"], size=30)
    pred = leave_one_out(ChiSquareNN, X, y)
    d = chi2_distances(X, X)
    np.fill_diagonal(d, np.inf)  # each sample may not vote for itself
    np.testing.assert_array_equal(pred, y[np.argmin(d, axis=1)])
    # Leave one group out: with groups, a sample's own group is excluded too.
    groups = np.arange(30) // 2
    pred_g = leave_one_out(ChiSquareNN, X, y, groups)
    same = groups[:, None] == groups[None, :]
    np.testing.assert_array_equal(pred_g, y[np.argmin(np.where(same, np.inf, d), axis=1)])


@pytest.mark.parametrize("method", ["nn", "svm"])
def test_esf_recognises_held_out_views_of_primitive_shapes(database, method):
    db, _ = database
    rec = Recognizer(db, descriptor="esf", method=method, size_weight=0.0)  # shape alone
    clouds, labels = held_out_views(shapes(), HeldOutParams(n_per_model=6, distance_range_m=(1.2, 2.0)), RES)
    conf = rec.evaluate(clouds, labels)
    assert conf.sum() == len(labels) == 24
    assert np.trace(conf) / conf.sum() >= 0.9, conf


def test_classify_returns_the_confusion_column_and_optionally_applies_connectivity(database):
    db, _ = database
    k = len(db.classes)
    conf = np.full((k, k), 2.0) + np.diag([20.0] * k)
    rec = Recognizer(db, confusion=conf)
    cls, mesh, _ = shapes()["tor"]
    clouds, _ = held_out_views({"tor": (cls, mesh, [])}, HeldOutParams(n_per_model=1, seed=9), RES)
    lik = rec.classify(clouds[0], None)
    assert set(lik) == set(db.classes)
    assert max(lik, key=lik.get) == "Torus"
    assert lik["Torus"] == pytest.approx(23 / (23 + 3 * (k - 1)))  # counts 22 / 2, smoothed by +1
    gated = Recognizer(db, confusion=conf, apply_connectivity=True)
    gated.connectivity.compatibility["Torus"] = frozenset({1})
    lik3 = gated.classify(clouds[0], 3)
    assert lik3["Torus"] == 0.0 and lik3["Sphere"] > 0.0  # classes without ports admit anything


def test_icp_pose_recovers_the_object_pose(database):
    db, _ = database
    rec = Recognizer(db, size_weight=0.2)
    cls, mesh, _ = shapes()["ell"]
    rng = np.random.default_rng(4)
    T_MC = look_at(np.array([0.9, -0.8, 0.9]), np.zeros(3), roll_rad=0.7)  # not a database view
    cloud = VirtualScanner(mesh).scan(T_MC, RES, 0.003, rng)
    T_SM_true = np.linalg.inv(T_MC)
    name, est = rec.pose(cloud)
    assert name == "ell"
    v = np.asarray(mesh.vertices)
    err = np.linalg.norm(
        (v @ est.T_SM[:3, :3].T + est.T_SM[:3, 3]) - (v @ T_SM_true[:3, :3].T + T_SM_true[:3, 3]), axis=1
    )
    assert est.fitness > 0.9
    assert err.max() < 0.02, err.max()
    angle = Rotation.from_matrix(est.T_SM[:3, :3].T @ T_SM_true[:3, :3]).magnitude()
    assert np.rad2deg(angle) < 5.0


def test_six_class_cad_library_held_out_esf_accuracy(request):
    cad = pytest.importorskip("semslam.models.cad")
    models = {n: (m.cls, m.mesh, list(m.ports)) for n, m in cad.library().items() if m.source is None}
    params = ViewParams(n_views=12, distances_m=(1.0, 1.8, 3.0))  # a lighter database than the default
    db = load_database(models, params, cache_dir=_view_cache(request), include_user_models=False)
    clouds, labels = held_out_views(models, HeldOutParams(n_per_model=8), RES)  # 1–2.5 m, random rolls
    for kwargs in ({}, {"method": "svm", "size_weight": 0.0}):  # ESF + size cue NN; pure ESF + SVM
        conf = Recognizer(db, **kwargs).evaluate(clouds, labels)
        assert np.trace(conf) / conf.sum() >= 0.9, (kwargs, conf)
    rec = Recognizer(db)
    # The connectivity table comes from the models' ports and agrees with the paper's.
    assert rec.connectivity.compatibility["Elbow"] == frozenset({1, 3})
    assert rec.connectivity.compatibility["R-Tee"] == frozenset({1, 2, 3, 4})
    json.dumps(rec.confusion.tolist())


def test_classify_degenerate_segments_is_uninformative_not_an_error(database):
    db, _ = database
    rec = Recognizer(db)
    assert rec.classify(np.zeros((5, 3), np.float32), None) == {c: 1.0 for c in db.classes}
    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)].astype(np.float32)
    assert rec.classify(line, None) == {c: 1.0 for c in db.classes}


def test_default_recognizer_calibrates_once_and_caches_the_syn_confusion(request, tmp_path, monkeypatch):
    from frontends.laser.recognition import recognizer as recmod

    params = ViewParams(n_views=12, distances_m=(1.2, 1.9))
    held = HeldOutParams(n_per_model=3, distance_range_m=(1.2, 2.0))
    views = _view_cache(request)
    rec = recmod.default_recognizer(models=shapes(), params=params, held_out=held, cache_dir=views)
    assert rec.confusion.sum() == 12 and rec.classes == ["Cylinder", "Sphere", "Torus", "L"]
    assert np.trace(rec.confusion) >= 10
    # The SYN confusion is cached with the views: a second recogniser does not re-calibrate.
    monkeypatch.setattr(recmod.Recognizer, "calibrate", lambda *a, **k: pytest.fail("re-calibrated"))
    again = recmod.default_recognizer(models=shapes(), params=params, held_out=held, cache_dir=views)
    np.testing.assert_array_equal(again.confusion, rec.confusion)
    # P(Z | X) is the smoothed, row-normalised SYN confusion.
    np.testing.assert_allclose(again.model.p_z_given_x.sum(axis=1), 1.0)


def test_recognition_config_validates_and_builds(request, monkeypatch):
    from pydantic import ValidationError

    from frontends.laser.recognition import config as cfgmod
    from frontends.laser.recognition import recognizer as recmod

    with pytest.raises(ValidationError):
        cfgmod.RecognitionConfig.model_validate({"descriptor": "shot"})
    with pytest.raises(ValidationError):
        cfgmod.RecognitionConfig.model_validate({"n_views": 6})  # fewer than the paper's 12
    seen = {}

    def fake(**kwargs):
        seen.update(kwargs)
        return "recognizer"

    monkeypatch.setattr(recmod, "default_recognizer", fake)
    out = cfgmod.recognizer_from_config({"method": "svm", "size_weight": 0.0, "n_views": 12, "distances_m": [1.5]})
    assert out == "recognizer"
    assert seen["method"] == "svm" and seen["size_weight"] == 0.0
    assert seen["params"].n_views == 12 and seen["params"].distances_m == (1.5,)
    assert seen["params"].angular_resolution_rad == pytest.approx(np.deg2rad(0.15))
