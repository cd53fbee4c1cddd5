"""The newest keyframe deferred to the next iSAM2 update (semslam.backend.keyframes): its predicted
estimate and covariance are what iSAM2 gives once its factors are committed."""

import numpy as np

from semslam.backend.graph import GraphEstimator
from semslam.backend.window import X
from semslam.config import SemslamConfig
from tests.support.synthetic_mission import SyntheticConfig, simulate


def test_deferred_keyframe_predicts_what_isam2_gives():
    # Navigation only, with a DVL dropout (a loosely held position): every keyframe after the first
    # waits for the next one, which commits it first.
    mission = simulate(SyntheticConfig(duration_s=45.0, dropouts=((20.0, 10.0),), ahrs_yaw_bias_rad=0.0, seed=4))
    est = GraphEstimator(mission.metadata, SemslamConfig(), batch=False)
    kf, checked, last, exact = est.keyframes, 0, 0, 0
    for m in mission:
        est.process_measurement(m)
        k = kf.newest
        if k < 1 or k % 3 or k == last:
            continue
        last = k
        assert est.session.is_pending(X(k)) and not est.session.isam.valueExists(X(k))
        assert not est.session.is_pending(X(k - 1))  # one keyframe waits at most
        pose, cov, vel = kf.pose, kf.pose_cov.copy(), kf.vel.copy()
        before = est.session.relinearized
        kf.flush()
        assert not est.session.pending and est.session.isam.valueExists(X(k))
        ref, ref_cov = est.session.pose(X(k)), est.session.root_marginal(X(k))
        sigma = np.sqrt(np.trace(ref_cov[3:, 3:]))
        d = np.sqrt(np.diag(ref_cov))
        # The prediction linearises X(k-1)'s factors at iSAM2's linearisation point, as iSAM2 does:
        # the same step to rounding unless this update relinearised a variable (iSAM2 says so). At X(k-1)'s
        # estimate instead (the code before stop 41) it was off by up to 1.2 % of σ while the DVL holds
        # (0.46 % at keyframe 3) and 41 % after the dropout.
        relinearised = est.session.relinearized > before
        if not relinearised:
            tol, rot_tol, cov_tol = 1e-8, 1e-12, 1e-8
        else:  # relinearisation moves iSAM2's step: 1 % of σ while the DVL holds, half a σ after the dropout
            tol, rot_tol, cov_tol = (1e-2, 1e-5, 1e-2) if k <= 18 else (0.5, 1e-5, 0.25)
        assert np.linalg.norm(pose.translation() - ref.translation()) < tol * sigma
        assert np.linalg.norm(pose.rotation().logmap(ref.rotation())) < rot_tol
        assert np.abs(vel - est.session.vector(kf.anchor()[1])).max() < max(1e-9, 2e-2 * tol)
        assert np.abs((cov - ref_cov) / np.outer(d, d)).max() < cov_tol
        exact += not relinearised
        checked += 1
    assert checked >= 12 and exact >= 10
    res = est.finish()
    assert len(res.trajectory) == len(kf) and not res.diagnostics
