"""Stop 47 (s47-f53, diagnosis): one field run with every sonar observation the graph is given logged.

Runs `run_comparison` as `semslam study` does (the study's config.yaml), with the sonar front-end's
`process` wrapped: each emitted observation (swath registrations as OdometryObservation, structure
views as StructureObservation) is recorded with the front-end's pose_at at its stamps, and after the
run the front-end's logs (accepted window registrations, structure re-observation rejections, patch
anchors). Then everything is compared with the bag's ground truth. Run it with the code to test first
on PYTHONPATH (e.g. a `git archive` of f5c3156):

    PYTHONPATH=/tmp/s47/s47-f53/code nice -n 5 .venv/bin/python experiments/estimators/f53_sonar_log.py \
        BAG CONFIG.yaml OUT.pkl
"""

from __future__ import annotations

import os
import pickle
import sys

import numpy as np


def structure_truth(mission) -> dict:
    """The true position of each structure model of the mission's ground-truth map (one per model)."""
    gt = mission.metadata.ground_truth
    structures = gt.structures if gt is not None else ()
    models = [s.model for s in structures]
    if len(set(models)) != len(models):
        raise SystemExit(f"{models}: a model more than once; the table keys the truth by model")
    return {s.model: tuple(s.position) for s in structures}


def main(bag: str, config_path: str, out: str) -> None:
    from frontends.sonar.frontend import SonarFrontend
    from semslam.compare import run_comparison
    from semslam.config import load_config
    from semslam.mission.bag import read_mission
    from semslam.observations import OdometryObservation, StructureObservation

    fes: list = []
    emitted: list[dict] = []
    process = SonarFrontend.process

    def logged(self, measurement, view=None):
        if not fes or fes[-1] is not self:
            fes.append(self)
        obs = process(self, measurement, view)
        for o in obs:
            row = {"stamp": int(o.stamp), "type": type(o).__name__, "T_now": self._pose(int(o.stamp))}
            if isinstance(o, OdometryObservation):
                row.update(stamp_from=int(o.stamp_from), rel=np.asarray(o.relative_pose), cov=np.asarray(o.covariance))
            elif isinstance(o, StructureObservation):
                row.update(
                    model=o.model, T_SM=np.asarray(o.pose), cov=np.asarray(o.covariance), T_BS=self._T_BS(o.sensor)
                )
            else:
                continue
            emitted.append(row)
        return obs

    SonarFrontend.process = logged

    # every re-observation's ICP from the prior, accepted or not: (model, patch, anchor stamp, emitted, fitness,
    # median, points, jump m, turn deg, gap m, its reobservation-log entry (None: emitted unsearched), ICPs run)
    import frontends.sonar.reobservation as reob

    icps: list = []
    views: list[tuple] = []
    views_T: list[tuple] = []
    icp = reob.icp

    def icp_logged(md, pts, T0, *args, **kw):
        reg = icp(md, pts, T0, *args, **kw)
        icps.append((np.asarray(T0), reg))
        return reg

    reob.icp = icp_logged
    observe = reob.StructureReobservation.observe

    def observe_logged(self, patch, ks, *args, **kw):
        n, nlog = len(icps), len(self.log)
        last_search.clear()
        obs = observe(self, patch, ks, *args, **kw)
        if len(icps) > n:
            # the ICP from the prior is the first (a searched view runs many more after it)
            T0, reg = icps[n]
            gap = kw.get("gap_m", args[7] if len(args) > 7 else 0.0)
            entry = self.log[nlog] if len(self.log) > nlog else None
            d = np.linalg.inv(T0) @ reg.T
            turn = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
            views.append(
                (
                    ks.model,
                    patch.id,
                    int(patch.anchor_stamp),
                    obs is not None,
                    reg.fitness,
                    reg.median_m,
                    reg.n_structure,
                    float(np.linalg.norm(d[:3, 3])),
                    float(turn),
                    float(gap),
                    entry,
                    len(icps) - n,
                )
            )
            views_T.append(
                (
                    np.asarray(reg.T),
                    last_search[-1][0] if last_search else None,
                    None
                    if obs is None
                    else {"stamp": int(obs.stamp), "T_SM": np.asarray(obs.pose), "cov": obs.covariance},
                    last_search[-1][1] if last_search else None,
                )
            )
        return obs

    reob.StructureReobservation.observe = observe_logged
    # a searched view's registration (the search's best fit), and each view's patch-frame poses: views_T
    # (parallel to views) = (ICP from the prior's T_AM, the search's T_AM or None, the emitted observation or None,
    # the search's fit: points, fitness, footprint coverage, unexplained share, translation covariance, or None)
    searched = reob.StructureReobservation._searched
    last_search: list = []

    # a diagnosis of one view's part: DROP="model:patch,..." refuses those searched views (reason "gap",
    # info ("dropped", ...)), as if the search had found no acceptable fit
    drop = {tuple(k.split(":")) for k in os.environ.get("DROP", "").split(",") if k}

    def searched_logged(self, patch, ks, *args, **kw):
        out = searched(self, patch, ks, *args, **kw)
        r = out[0]
        fit = {"n_structure": r.n_structure, "fitness": r.fitness, "coverage": r.coverage}
        fit.update(unexplained=r.unexplained, cov_t=np.asarray(r.cov)[3:, 3:])
        last_search.append((np.asarray(r.T), fit))
        if (ks.model, str(patch.id)) in drop and out[1] is None:
            out = (out[0], "gap", ("dropped", *out[2]))
        return out

    reob.StructureReobservation._searched = searched_logged
    config = load_config(config_path)
    mission = read_mission(bag, config.reader)
    result, metrics = run_comparison(mission, config, None, frontend_workers=1)
    fe = fes[-1]
    truth = result.truth
    dump = {
        "emitted": emitted,
        "accepted": fe.windows.accepted,
        "window_log": fe.windows.log,
        "reobservation_log": fe.reobservation.log,
        "anchors": {p.id: int(p.anchor_stamp) for p in fe.patches},
        "truth": (np.asarray(truth.stamps), np.asarray(truth.positions), np.asarray(truth.orientations)),
        "sonar": metrics.get("sonar"),
        "views": views,
        "views_T": views_T,
        "structures": structure_truth(mission),
    }
    try:
        dump["ate"] = {k: v.get("ate_rmse_m") for k, v in metrics["estimators"].items()}
    except Exception:  # noqa: BLE001 - a diagnosis: the log matters, not the summary
        dump["ate"] = None
    with open(out, "wb") as f:
        pickle.dump(dump, f)
    print("emitted", len(emitted), "accepted", len(fe.windows.accepted), "ate", dump["ate"])


if __name__ == "__main__":
    main(*sys.argv[1:4])
