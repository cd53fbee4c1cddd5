"""Class posteriors: confusion model, Bayesian fusion, connectivity constraints, stage metrics."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.metrics import precision_recall_fscore_support

from semslam.semantics import (
    ClassFusion,
    ConfusionModel,
    ConnectivityTable,
    ObservationRecord,
    classification_metrics,
    compatible_configurations,
    configuration_of,
    confusion_matrix,
    fuse,
    recognition_metrics,
)
from semslam.semantics.connectivity import DEFAULT_COMPATIBILITY, most_restrictive
from semslam.semantics.metrics import format_table, stage_predictions

CLASSES = ["Ball-Valve", "Elbow", "R-Tee", "R-Socket", "Butterfly-Valve", "3-Way-Ball-Valve"]


def noisy_confusion(acc: float, n: int = 100) -> np.ndarray:
    """Counts with ``acc`` on the diagonal and the rest spread over the other classes."""
    k = len(CLASSES)
    c = np.full((k, k), n * (1 - acc) / (k - 1))
    np.fill_diagonal(c, n * acc)
    return c


def test_confusion_model_is_row_normalised_and_gives_columns():
    c = np.diag([8.0, 6, 4, 2, 1, 9]) + 1.0
    m = ConfusionModel(c, CLASSES, smoothing=0.0)
    np.testing.assert_allclose(m.p_z_given_x.sum(axis=1), 1.0)
    lik = m.likelihood("R-Tee")
    assert lik["R-Tee"] == pytest.approx(5 / 10)
    assert lik["Elbow"] == pytest.approx(1 / 12)  # R-Tee column of the Elbow row (7 + 5·1)
    soft = m.likelihood_soft({"R-Tee": 1.0})
    assert soft == pytest.approx(lik)
    # Smoothing keeps a never-confused pair possible.
    m2 = ConfusionModel(np.diag([10.0] * 6), CLASSES, smoothing=1.0)
    assert min(m2.likelihood("Elbow").values()) > 0
    with pytest.raises(ValueError):
        ConfusionModel(np.eye(3), CLASSES)


@pytest.mark.parametrize("true_cls", CLASSES)
def test_posterior_converges_to_true_class_under_noisy_likelihoods(true_cls):
    rng = np.random.default_rng(CLASSES.index(true_cls))
    model = ConfusionModel(noisy_confusion(0.5), CLASSES)  # a weak recogniser: right half the time
    fusion = ClassFusion(CLASSES)
    row = model.p_z_given_x[CLASSES.index(true_cls)]
    p_true = []
    for _ in range(40):
        z = CLASSES[rng.choice(len(CLASSES), p=row)]
        fusion.update(7, model.likelihood(z))
        p_true.append(fusion.posterior(7)[true_cls])
    assert fusion.map_class(7) == true_cls
    assert p_true[-1] > 0.999
    assert np.mean(p_true[-10:]) > np.mean(p_true[:5])
    assert sum(fusion.posterior(7).values()) == pytest.approx(1.0)
    assert fusion.n_observations(7) == 40


def test_unobserved_landmark_has_the_prior_and_long_sequences_do_not_underflow():
    fusion = ClassFusion(CLASSES, prior={c: (2.0 if c == "Elbow" else 1.0) for c in CLASSES})
    assert fusion.posterior("x")["Elbow"] == pytest.approx(2 / 7)
    lik = {c: 1e-3 for c in CLASSES} | {"R-Tee": 2e-3}
    for _ in range(2000):  # Π 1e-3 underflows in linear space after ~100 factors
        fusion.update("x", lik)
    post = fusion.posterior("x")
    assert post["R-Tee"] == pytest.approx(1.0)
    assert all(np.isfinite(v) for v in post.values())


def test_connectivity_zeroes_incompatible_classes():
    fusion = ClassFusion(CLASSES)
    flat = {c: 1.0 for c in CLASSES}
    fusion.update(1, flat, configuration=1)
    assert all(v > 0 for v in fusion.posterior(1).values())  # one pipe fits every class
    fusion.update(1, flat, configuration=3)  # two orthogonal pipes
    post = fusion.posterior(1)
    assert {c for c, v in post.items() if v > 0} == {"Elbow", "R-Tee", "3-Way-Ball-Valve"}
    assert post["Ball-Valve"] == 0.0 and post["R-Socket"] == 0.0
    # A later, less restrictive configuration does not undo the constraint.
    fusion.update(1, flat, configuration=1)
    assert fusion.posterior(1)["Ball-Valve"] == 0.0
    fusion.update(1, flat, configuration=2)  # 2 and 3 seen: only the three-port classes fit both
    assert {c for c, v in fusion.posterior(1).items() if v > 0} == {"R-Tee", "3-Way-Ball-Valve"}
    assert fusion.configuration(1) == 4
    # BAYS (no connectivity) is untouched.
    assert fusion.posterior(1, use_connectivity=False)["Ball-Valve"] == pytest.approx(1 / 6)

    f2 = ClassFusion(CLASSES)
    f2.update(2, flat, configuration=4)
    assert {c for c, v in f2.posterior(2).items() if v > 0} == {"R-Tee", "3-Way-Ball-Valve"}


def test_connectivity_overrides_a_confident_but_wrong_descriptor():
    model = ConfusionModel(noisy_confusion(0.6), CLASSES)
    fusion = ClassFusion(CLASSES)
    for _ in range(3):  # an elbow repeatedly recognised as a ball valve...
        fusion.update(5, model.likelihood("Ball-Valve"), configuration=3)  # ...with two orthogonal pipes
    assert fusion.map_class(5, use_connectivity=False) == "Ball-Valve"
    assert fusion.map_class(5) in {"Elbow", "R-Tee", "3-Way-Ball-Valve"}


def test_conflicting_connectivity_is_dropped_not_a_zero_posterior():
    table = ConnectivityTable({"A": {1, 2}, "B": {1, 2}})
    fusion = ClassFusion(["A", "B"], connectivity=table)
    fusion.update(0, {"A": 0.9, "B": 0.1}, configuration=4)
    assert fusion.conflict(0)
    assert fusion.posterior(0) == pytest.approx({"A": 0.9, "B": 0.1})


def test_an_open_class_set_grows_with_the_likelihoods():
    """An estimator knows the classes only from the likelihoods it gets: a class named later enters
    with likelihood 0 (floored) in the views fused before, as a class a view does not name."""
    fusion = ClassFusion(None)
    assert fusion.posterior(1) == {}
    fusion.update(1, {"A": 0.7, "B": 0.3})
    fusion.update(1, {"A": 0.6, "B": 0.4}, configuration=1)
    fusion.update(2, {"C": 0.9, "A": 0.1})
    closed = ClassFusion(["A", "B", "C"])
    for lid, lik in ((1, {"A": 0.7, "B": 0.3}), (1, {"A": 0.6, "B": 0.4}), (2, {"C": 0.9, "A": 0.1})):
        closed.update(lid, lik)
    for lid in (1, 2):
        assert fusion.posterior(lid) == pytest.approx(closed.posterior(lid))
    assert fusion.posterior(1)["C"] < 1e-20 and fusion.n_observations(1) == 2
    with pytest.raises(ValueError):
        ClassFusion(None, prior={"A": 1.0})


def test_merge_pools_evidence():
    fusion = ClassFusion(CLASSES)
    fusion.update("a", {c: (0.9 if c == "Elbow" else 0.02) for c in CLASSES})
    fusion.update("b", {c: (0.9 if c == "Elbow" else 0.02) for c in CLASSES}, configuration=3)
    before = fusion.posterior("a")["Elbow"]
    fusion.merge("a", "b")
    assert "b" not in list(fusion.landmarks())
    assert fusion.posterior("a")["Elbow"] > before
    assert fusion.configuration("a") == 3


def test_configuration_from_pipe_directions():
    assert configuration_of([]) is None
    assert configuration_of([[1, 0, 0]]) == 1
    assert configuration_of([[1, 0, 0], [-1, 0.05, 0]]) == 2
    assert configuration_of([[1, 0, 0], [0, 0, 1]]) == 3
    assert configuration_of([[1, 0, 0], [-1, 0, 0], [0, 1, 0]]) == 4
    assert most_restrictive([1, 3, None, 1]) == 3
    assert most_restrictive([]) is None


def test_default_table_matches_port_geometry():
    x, y = [1, 0, 0], [0, 1, 0]
    mx = [-1, 0, 0]
    ports = {"in-line": [x, mx], "elbow": [x, y], "tee": [x, mx, y]}
    assert compatible_configurations(ports["in-line"]) == DEFAULT_COMPATIBILITY["Ball-Valve"]
    assert compatible_configurations(ports["in-line"]) == DEFAULT_COMPATIBILITY["R-Socket"]
    assert compatible_configurations(ports["elbow"]) == DEFAULT_COMPATIBILITY["Elbow"]
    assert compatible_configurations(ports["tee"]) == DEFAULT_COMPATIBILITY["R-Tee"]
    assert compatible_configurations(ports["tee"]) == DEFAULT_COMPATIBILITY["3-Way-Ball-Valve"]
    assert compatible_configurations([]) == frozenset()


def test_metrics_match_sklearn():
    rng = np.random.default_rng(0)
    true = list(rng.choice(CLASSES[:5], size=300))  # one class never occurs
    pred = [t if rng.random() < 0.7 else CLASSES[rng.integers(6)] for t in true]
    c = confusion_matrix(true, pred, CLASSES)
    assert c.sum() == 300 and c[5].sum() == 0
    m = classification_metrics(c, CLASSES)
    labels = CLASSES[:5]  # macro over the classes present in the truth
    p, r, f, _ = precision_recall_fscore_support(true, pred, labels=labels, average=None, zero_division=0)
    assert m["precision"] == pytest.approx(p.mean())
    assert m["recall"] == pytest.approx(r.mean())
    assert m["f1"] == pytest.approx(f.mean())
    assert m["accuracy"] == pytest.approx(np.mean(np.array(true) == np.array(pred)))
    assert m["per_class"]["Elbow"]["f1"] == pytest.approx(f[1])
    empty = classification_metrics(np.zeros((6, 6)), CLASSES)
    assert empty["accuracy"] is None and empty["f1"] is None


def _synthetic_mission(rng, acc=0.55, n_landmarks=30, obs_per_landmark=(3, 12)):
    """Landmarks of random classes, each seen several times by a recogniser with the given
    accuracy, with the pipe configuration of the true class seen now and then."""
    model = ConfusionModel(noisy_confusion(acc), CLASSES)
    ports = {
        "Ball-Valve": [1, 2], "Butterfly-Valve": [1, 2], "R-Socket": [1, 2],
        "Elbow": [1, 3], "R-Tee": [1, 2, 3, 4], "3-Way-Ball-Valve": [1, 2, 3, 4],
    }  # fmt: skip
    events = []
    for lid in range(n_landmarks):
        cls = CLASSES[lid % len(CLASSES)]
        row = model.p_z_given_x[CLASSES.index(cls)]
        for t in range(rng.integers(*obs_per_landmark)):
            z = CLASSES[rng.choice(len(CLASSES), p=row)]
            conf = rng.choice(ports[cls]) if rng.random() < 0.5 else None
            events.append((rng.random() + t, ObservationRecord(cls, model.likelihood(z), lid, conf)))
    events.sort(key=lambda e: e[0])  # landmarks interleaved in time
    return [r for _, r in events], model


def test_stages_improve_desc_bays_sem_on_a_synthetic_sequence():
    rng = np.random.default_rng(11)
    records, model = _synthetic_mission(rng)
    syn = noisy_confusion(0.55)
    m = recognition_metrics(records, CLASSES, syn_confusion=syn)
    assert set(m) == {"SYN", "DESC", "BAYS", "SEM"}
    assert m["SYN"]["accuracy"] == pytest.approx(0.55)
    assert m["DESC"]["n"] == m["BAYS"]["n"] == m["SEM"]["n"] == len(records)
    assert m["DESC"]["accuracy"] == pytest.approx(0.55, abs=0.08)
    assert m["DESC"]["f1"] < m["BAYS"]["f1"] <= m["SEM"]["f1"]
    final = recognition_metrics(records, CLASSES, mode="final")
    # The finished map, after all the evidence, is better still than the online answers.
    assert final["SEM"]["f1"] >= m["SEM"]["f1"] and final["BAYS"]["f1"] >= m["BAYS"]["f1"]
    assert final["SEM"]["f1"] > m["DESC"]["f1"] + 0.2
    table = format_table(m)
    assert "| SEM |" in table and "SYN confusion" in table


def test_unassociated_observations_are_not_fused():
    lik_a = {c: (0.9 if c == "Elbow" else 0.02) for c in CLASSES}
    lik_b = {c: (0.9 if c == "R-Tee" else 0.02) for c in CLASSES}
    recs = [ObservationRecord("Elbow", lik_a), ObservationRecord("R-Tee", lik_b)]
    preds = stage_predictions(recs, CLASSES)
    assert preds["BAYS"] == ["Elbow", "R-Tee"]


def test_stateless_fuse_matches_the_incremental_fusion():
    model = ConfusionModel(noisy_confusion(0.6), CLASSES)
    liks = [model.likelihood(z) for z in ["Elbow", "Ball-Valve", "Elbow"]] + [None]  # None: no recognition
    f = ClassFusion(CLASSES)
    for lik in liks:
        if lik:
            f.update(3, lik, configuration=3)
    assert fuse(liks, [3, 3, 3]) == pytest.approx(f.posterior(3))
    assert fuse(liks) == pytest.approx(f.posterior(3, use_connectivity=False))
    assert fuse([None, {}]) is None
    # Classes are taken from the likelihoods' keys when not given.
    assert set(fuse([{"a": 0.9, "b": 0.1}])) == {"a", "b"}


def test_semantic_map_entry_reports_posterior_and_map_class():
    model = ConfusionModel(noisy_confusion(0.7), CLASSES)
    fusion = ClassFusion(CLASSES)
    for z in ["R-Tee", "Elbow", "R-Tee"]:
        fusion.update(42, model.likelihood(z), configuration=2)
    entry = fusion.summary(42)
    assert entry["class"] == "R-Tee" == max(entry["posterior"], key=entry["posterior"].get)
    assert entry["posterior"]["Elbow"] == 0.0  # two collinear pipes: not an elbow
    assert entry["n_observations"] == 3 and entry["configuration"] == 2
    assert entry["connectivity_conflict"] is False
    assert sum(entry["posterior"].values()) == pytest.approx(1.0)


def test_a_rare_wrong_configuration_does_not_rule_out_the_true_class():
    """An elbow seen 60 times with two orthogonal pipes and twice with three (a passing pipe taken
    for its third) stays an elbow; the same three-pipe views, a fifth of them, do count."""
    flat = {c: 1.0 for c in CLASSES}
    elbowish = {c: (0.5 if c == "Elbow" else 0.4 if c == "R-Tee" else 0.02) for c in CLASSES}
    fusion = ClassFusion(CLASSES)
    for k in range(62):
        fusion.update(7, elbowish, configuration=4 if k in (3, 40) else 3)
    assert fusion.map_class(7) == "Elbow" and fusion.configuration(7) == 3
    strict = ClassFusion(CLASSES, min_configuration_fraction=0.0)  # the paper's rule: every view counts
    for k in range(62):
        strict.update(7, elbowish, configuration=4 if k in (3, 40) else 3)
    assert strict.posterior(7)["Elbow"] == 0.0 and strict.configuration(7) == 4
    for _ in range(15):  # now 17 of 77 views show three pipes: a real third pipe
        fusion.update(7, flat, configuration=4)
    assert fusion.posterior(7)["Elbow"] == 0.0 and fusion.configuration(7) == 4
    with pytest.raises(ValueError):
        ClassFusion(CLASSES, min_configuration_fraction=1.5)


def test_posteriors_read_between_changes_follow_every_change():
    """Posteriors are kept between reads (a map is read far more often than it changes): a read after
    each update, merge, forget or new class gives what a fusion that was never read gives."""
    rng = np.random.default_rng(3)
    read, fresh = ClassFusion(None), ClassFusion(None)
    steps = []
    for _ in range(60):
        lid = int(rng.integers(4))
        names = ["A", "B", "C", "D"][: int(rng.integers(2, 5))]  # new classes come in as it goes
        lik = dict(zip(names, rng.dirichlet(np.ones(len(names))).tolist()))
        steps.append(("update", lid, lik, int(rng.integers(1, 5))))
    steps[20:20] = [("merge", 0, 1, None)]
    steps[40:40] = [("forget", 2, None, None)]
    for op, a, b, c in steps:
        for f in (read, fresh):
            if op == "update":
                f.update(a, b, configuration=c)
            elif op == "merge":
                f.merge(a, b)
            else:
                f.forget(a)
        for lid in range(4):  # only ``read`` is read between the changes
            read.posterior(lid), read.posterior(lid, use_connectivity=False), read.conflict(lid)
    for lid in range(4):
        for conn in (True, False):
            assert read.posterior(lid, conn) == pytest.approx(fresh.posterior(lid, conn), abs=1e-12)
        assert read.map_class(lid) == fresh.map_class(lid)
