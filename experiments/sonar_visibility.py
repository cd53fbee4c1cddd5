"""Did the sonar's fan ever reach a structure's top? Per structure of each field bag, with the true poses:

* ``reach``: over the mission, the smallest horizontal distance from the sonar to the structure's centre
  divided by the fan's half-width at the depth of the structure's top (vertical clearance × tan(half
  swath)); above 1 the top's centre lies outside every swath (the lines pass too far to its side for
  the clearance);
* ``hmax``: the highest cell of the recognition's elevation map (upper surface, Δ cell, seabed
  estimated as online) over the model's footprint disc, against the model's own height;
* ``score``: the descriptor's best normalised score within 0.5 m of the true centre (threshold 0.40);
* ``icp``: fitness of the ICP from the true pose and whether it passes the new structure's quality test.

    python experiments/sonar_visibility.py FIELD.bag [FIELD.bag ...]
"""

from __future__ import annotations

import sys

import numpy as np

from frontends.sonar.config import SonarConfig
from frontends.sonar.descriptor import search
from frontends.sonar.recognition import Recogniser
from frontends.sonar.registration import icp
from semslam.mission.bag_reader import read_mission
from semslam.mission.measurements import GroundTruthPose, SonarSwath
from semslam.models.structures import structure_library


def structure_rows(bag: str, rec: Recogniser, cfg: SonarConfig) -> list[dict]:
    """One row per ground-truth structure of the mission in ``bag`` (see the module's docstring)."""
    mission = read_mission(bag)
    lib = {m.name: m for m in rec.models}
    gts = list(mission.metadata.ground_truth.structures)
    T_BS = np.asarray(mission.metadata.sensors["sonar"].T_BS, float)
    sim = mission.metadata.extras.get("simulator", {}).get("config", {})
    half = np.radians(0.5 * float(sim.get("sonar", {}).get("swath_deg", 80.0)))
    gt: dict[int, np.ndarray] = {}
    pts: dict[int, list[np.ndarray]] = {k: [] for k in range(len(gts))}
    sonar_xyz = []
    for m in mission:
        if isinstance(m, GroundTruthPose):
            gt[m.stamp] = m.matrix()
        elif isinstance(m, SonarSwath) and m.stamp in gt:
            T = gt[m.stamp] @ T_BS
            sonar_xyz.append(T[:3, 3])
            W = m.points() @ T[:3, :3].T + T[:3, 3]
            for k, g in enumerate(gts):
                pts[k].append(W[np.hypot(W[:, 0] - g.position[0], W[:, 1] - g.position[1]) <= 7.0])
    S = np.asarray(sonar_xyz)
    rows = []
    for k, g in enumerate(gts):
        model = lib[g.model]
        P = np.concatenate(pts[k])
        height = -float(np.asarray(model.mesh.vertices)[:, 2].min())
        top_z = g.position[2] - height
        lateral = np.hypot(S[:, 0] - g.position[0], S[:, 1] - g.position[1])
        reach = float(np.min(lateral / np.maximum((top_z - S[:, 2]) * np.tan(half), 1e-6)))
        em, _, h = rec.heights(P)
        N, E = em.spec.centres()
        tpl = rec.templates[g.model]
        ii, jj = np.mgrid[0 : h.shape[0], 0 : h.shape[1]]
        d = np.hypot(N[ii] - g.position[0], E[jj] - g.position[1])
        sel = (d <= 0.5) & np.isfinite(h)
        res = search(tpl.spec.bin_of(h), tpl, np.column_stack([ii[sel], jj[sel]]), 3.0 * tpl.flat_score, 0.0)
        disc = d <= model.footprint_radius
        T_true = g.matrix()
        near = P[np.hypot(P[:, 0] - g.position[0], P[:, 1] - g.position[1]) <= model.footprint_radius + 0.5]
        reg = icp(rec.model_data[g.model], near, T_true, cfg.registration)
        rows.append(
            {
                "model": g.model,
                "reach": reach,
                "hmax": float(np.nanmax(h[disc])),
                "height": height,
                "score": None if res.centre is None else res.score / tpl.flat_score,
                "icp_fitness": float(reg.fitness),
                "quality": rec.quality_test(g.model, near, reg) is not None,
            }
        )
    return rows


def main(argv: list[str]) -> None:
    cfg = SonarConfig()
    rec = Recogniser(list(structure_library().values()), cfg.recognition, cfg.registration)
    print("| bag | model | reach | hmax / height (m) | score (0.40) | ICP from truth: fitness, quality |")
    print("|---|---|---|---|---|---|")
    for bag in argv:
        for r in structure_rows(bag, rec, cfg):
            score = "–" if r["score"] is None else f"{r['score']:.3f}"
            print(
                f"| {bag.rsplit('/', 1)[-1]} | {r['model']} | {r['reach']:.2f} | {r['hmax']:.2f} / {r['height']:.2f} "
                f"| {score} | {r['icp_fitness']:.3f}, {r['quality']} |",
                flush=True,
            )


if __name__ == "__main__":
    main(sys.argv[1:])
