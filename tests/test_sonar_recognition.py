"""Sonar front-end: recognition of the CAD structures (right model, right place, nothing on the
seabed or a pipeline) and their 4-D + ICP registration, on a short simulated survey placed with
the true poses."""

import numpy as np
import pytest

from frontends.sonar.config import RecognitionConfig, StructureRegistrationConfig
from frontends.sonar.grid import ElevationMap, estimate_ground
from frontends.sonar.recognition import Recogniser
from frontends.sonar.registration import icp, model_data, register_structure
from semslam.models.structures import structure_library
from semslam.sim.field import make_field
from semslam.sim.field_config import FieldSimConfig
from semslam.sim.field_mission import simulate_field
from tests.support.sonar_survey import survey_config, true_points, true_structure_pose, yaw_error


@pytest.fixture(scope="module")
def survey():
    """Three 34 m lines of seed 0's field (256 beams): the manifold, the PLET and the wellhead in view."""
    m = simulate_field(
        survey_config(
            seed=0, lines=3, line_length_m=34.0, centre="manifold", east_offset_m=-2.0, sonar={"n_beams": 256}
        )
    )
    return m, true_points(m).astype(np.float32)


@pytest.fixture(scope="module")
def recogniser():
    return Recogniser(list(structure_library().values()), RecognitionConfig(), StructureRegistrationConfig())


def test_recognises_every_structure_with_the_right_model_and_place(survey, recogniser):
    m, pts = survey
    dets = recogniser.recognise(pts.astype(float))
    assert sorted(d.model for d in dets) == ["manifold", "plet", "wellhead"]
    for d in dets:
        T_true = true_structure_pose(m, d.model)
        model = structure_library()[d.model]
        assert d.normalised < recogniser.cfg.threshold
        reg = d.registration
        assert np.linalg.norm(reg.T[:3, 3] - T_true[:3, 3]) < 0.03, d.model
        assert np.degrees(yaw_error(reg.T, T_true, model.symmetry)) < 1.0, d.model
        assert reg.median_m < 0.03 and reg.fitness > 0.9


def test_rejects_the_seabed_and_a_pipeline(survey, recogniser):
    """Around pipeline 0's middle (a 0.5 m pipe on the relief) nothing is recognised, even with
    the height trigger off; with the threshold raised tenfold the same search would find something."""
    m, pts = survey
    pipe = m.metadata.ground_truth.pipes[0]
    mid = 0.5 * (np.array(pipe.p[:2]) + np.array(pipe.q[:2]))
    cfg = recogniser.cfg.model_copy(update={"trigger_height_m": 0.0})
    rec = Recogniser(recogniser.models, cfg, recogniser.reg_cfg)
    lo, hi = mid - 1.5, mid + 1.5
    far = np.hypot(pts[:, 0] - mid[0], pts[:, 1] - mid[1]) < 7.0
    # the search region avoids every structure's disc (they are > 3.5 m from the pipe's middle)
    for s in m.metadata.ground_truth.structures:
        assert np.hypot(*(np.array(s.position[:2]) - mid)) > structure_library()[s.model].footprint_radius + 1.5
    assert rec.recognise(pts[far].astype(float), lo, hi, register=False) == []
    loose = Recogniser(recogniser.models, cfg.model_copy(update={"threshold": 3.0}), recogniser.reg_cfg)
    assert loose.recognise(pts[far].astype(float), lo, hi, register=False) != []


@pytest.mark.parametrize("model,offset", [("manifold", (0.6, -0.5))])
def test_registration_recovers_a_known_pose(survey, model, offset):
    """From a centre off by tens of centimetres and no yaw, the 4-D search then ICP recover the
    true pose (yaw modulo the model's symmetry)."""
    m, pts = survey
    T_true = true_structure_pose(m, model)
    lib = structure_library()
    cfg = StructureRegistrationConfig()
    md = model_data(lib[model], cfg)
    centre = T_true[:2, 3] + np.array(offset)
    near = np.hypot(pts[:, 0] - centre[0], pts[:, 1] - centre[1]) < lib[model].footprint_radius + 1.5
    P = pts[near].astype(float)
    em = ElevationMap.from_points(P, 0.08, quantile=0.1)
    ground = ElevationMap(em.spec, estimate_ground(em.depth, 0.08), em.count)
    gd = ground.sample(P[:, 0], P[:, 1])
    ok = np.isfinite(gd)
    pts_h = np.column_stack([P[ok, :2], gd[ok] - P[ok, 2]])
    g0 = float(np.nanmedian(gd))
    reg = register_structure(md, pts_h, P, centre, g0, cfg)
    assert np.linalg.norm(reg.T[:3, 3] - T_true[:3, 3]) < 0.02
    assert np.degrees(yaw_error(reg.T, T_true, lib[model].symmetry)) < 1.0
    assert reg.median_m < 0.02
    # and ICP alone, from a pose 8 cm / 3° off, comes back too (the re-observation path)
    c, s = np.cos(np.radians(3)), np.sin(np.radians(3))
    D = np.eye(4)
    D[:2, :2] = [[c, -s], [s, c]]
    D[:3, 3] = [0.05, -0.06, 0.02]
    reg2 = icp(md, P, T_true @ D, cfg)
    assert np.linalg.norm(reg2.T[:3, 3] - T_true[:3, 3]) < 0.02
    assert np.degrees(yaw_error(reg2.T, T_true, lib[model].symmetry)) < 0.5


@pytest.mark.xfail(
    strict=True,
    reason="issue 21: the descriptor refuses a structure whose top the fan never reached (scores 0.43-0.46 "
    "against 0.40); 0.50 recognises it but cost the graph's ATE on new fields 78, 80, 83 "
    "(experiments/estimators/README.md, stop 51)",
)
def test_recognises_a_structure_whose_top_the_fan_never_reached():
    """Two 12 m lines 2.3 m either side of seed 0's wellhead at 4.3 m altitude: the fan (±40°) reaches
    about 1.3 m to the side at the depth of its top, so neither line sees its upper 0.6 m (the disc's
    highest cell is ~0.6 m below the model's top) and its upper rings hold lower surfaces seen under the
    deck. The default configuration still recognises it, registered at the right place."""
    lib = structure_library()
    st = next(s for s in make_field(FieldSimConfig(seed=0)).structures if s.model == "wellhead")
    m = simulate_field(
        survey_config(
            seed=0,
            lines=2,
            line_length_m=12.0,
            centre=(float(st.position[0]), float(st.position[1])),
            sonar={"n_beams": 256},
            trajectory={"line_spacing_m": 4.6, "altitude_m": 4.3},
        )
    )
    pts = true_points(m).astype(float)
    rec = Recogniser([lib["wellhead"]], RecognitionConfig(), StructureRegistrationConfig())
    em, _, h = rec.heights(pts)
    N, E = em.spec.centres()
    disc = np.hypot(N[:, None] - st.position[0], E[None, :] - st.position[1]) <= lib["wellhead"].footprint_radius
    height = -float(np.asarray(lib["wellhead"].mesh.vertices)[:, 2].min())
    assert np.nanmax(h[disc]) < height - 0.4  # the top was never seen
    dets = rec.recognise(pts)
    assert [d.model for d in dets] == ["wellhead"]
    T_true = true_structure_pose(m, "wellhead")
    assert np.linalg.norm(dets[0].registration.T[:3, 3] - T_true[:3, 3]) < 0.03
    assert np.degrees(yaw_error(dets[0].registration.T, T_true, lib["wellhead"].symmetry)) < 1.0
