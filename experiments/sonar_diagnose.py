"""Why a structure of a study mission (kept bag) was missed: its returns within 6 m of the truth placed
with the true poses and with the final graph; the descriptor's best normalised score within 0.5 m of
the true centre (recognition threshold 0.40), the disc's filled share and highest cell, what the
recogniser finds there, and the ICP from the true pose with the quality test.

    python experiments/sonar_diagnose.py STUDY_DIR/MISSION MODEL
"""

import sys
from pathlib import Path

import numpy as np

from frontends.sonar.config import SonarConfig
from frontends.sonar.descriptor import search
from frontends.sonar.recognition import Recogniser
from frontends.sonar.registration import icp
from semslam.estimation import Trajectory
from semslam.eval.structures import pose_at
from semslam.mission.bag_reader import read_mission
from semslam.mission.measurements import GroundTruthPose, SonarSwath
from semslam.models.structures import structure_library


def main(argv: list[str]) -> None:
    d = Path(argv[0])
    model = argv[1]
    mission = read_mission(d / "mission.bag")
    g = next(s for s in mission.metadata.ground_truth.structures if s.model == model)
    T_true = g.matrix()
    a = np.loadtxt(d / "trajectory_graph.tum")
    graph_at = pose_at(Trajectory((a[:, 0] * 1e9).round().astype(np.int64), a[:, 1:4], a[:, 4:8]), clip=True)
    T_BS = mission.metadata.sensors["sonar"].T_BS
    gt = {}
    true_pts, est_pts, stamps = [], [], []
    for m in mission:
        if isinstance(m, GroundTruthPose):
            gt[m.stamp] = m.matrix()
        elif isinstance(m, SonarSwath) and m.stamp in gt:
            P = m.points()
            for T, out in ((gt[m.stamp] @ T_BS, true_pts), (graph_at(m.stamp) @ T_BS, est_pts)):
                W = P @ T[:3, :3].T + T[:3, 3]
                near = np.hypot(W[:, 0] - g.position[0], W[:, 1] - g.position[1]) <= 6.0
                out.append(W[near])
            if len(true_pts[-1]):
                stamps.append(m.stamp)
    cfg = SonarConfig()
    lib = structure_library()
    rec = Recogniser([lib[model]], cfg.recognition, cfg.registration)
    t0 = min(gt)
    print(
        "swaths near",
        len(stamps),
        "t",
        (min(stamps) - t0) * 1e-9 if stamps else None,
        (max(stamps) - t0) * 1e-9 if stamps else None,
    )
    R = lib[model].footprint_radius
    for label, pts in (("true", np.concatenate(true_pts)), ("graph", np.concatenate(est_pts))):
        em, ground, h = rec.heights(pts)
        N, E = em.spec.centres()
        ii, jj = np.mgrid[0 : h.shape[0], 0 : h.shape[1]]
        tpl = rec.templates[model]
        sel = (np.hypot(N[ii] - g.position[0], E[jj] - g.position[1]) <= 0.5) & np.isfinite(h)
        cand = np.column_stack([ii[sel], jj[sel]])
        res = search(tpl.spec.bin_of(h), tpl, cand, 3.0 * tpl.flat_score, 0.0, rec.cfg.min_ring_coverage)
        disc = np.hypot(N[ii] - g.position[0], E[jj] - g.position[1]) <= R
        print(
            label,
            "points",
            len(pts),
            "filled share of disc",
            float(np.isfinite(h[disc]).mean()),
            "max height",
            float(np.nanmax(h[disc])),
            "best score",
            None if res.centre is None else round(res.score / tpl.flat_score, 3),
            "coverage",
            None if res.centre is None else round(res.coverage, 3),
            "threshold",
            cfg.recognition.threshold,
            "min_coverage",
            cfg.recognition.min_coverage,
        )
        dets = rec.recognise(pts, ground_kw=None)
        print(
            "  recognise:",
            [
                (
                    dd.model,
                    dd.centre.round(2).tolist(),
                    round(dd.normalised, 3),
                    round(dd.coverage, 3),
                    dd.registration is not None,
                )
                for dd in dets
            ],
            "rejected",
            [(dd.centre.round(2).tolist(), round(dd.normalised, 3)) for dd in rec.rejected],
        )
        rec.rejected.clear()
        near = np.hypot(pts[:, 0] - g.position[0], pts[:, 1] - g.position[1]) <= R + 0.5
        reg = icp(rec.model_data[model], pts[near], T_true, cfg.registration)
        print(
            "  ICP from truth: fitness",
            round(reg.fitness, 3),
            "median",
            round(reg.median_m, 4),
            "n_structure",
            reg.n_structure,
            "quality_test",
            rec.quality_test(model, pts[near], reg) is not None,
        )


if __name__ == "__main__":
    main(sys.argv[1:])
