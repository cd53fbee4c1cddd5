"""A valve's object views followed through the map core (issue 22, stop 43: "every valve mapped once"):
the laser observations that ``experiments/laser_real_eval.py pipeline --dump DIR`` recorded, fed again to
the graph (as ``pipeline_replay.py``), with every event of the map core near each true valve logged:
the object views within ``--reach`` of it (paired with a mapped landmark, to a track, or neither: the
builder judged them a mapped landmark seen badly), each track's counts after the view (views, scans
with its place in view, scans seen, the seen scans inherited from lapsed tracks), promotions, lapses
(timeout), tracks forgotten as ambiguous, inheritances, duplicate merges and the end-of-mission
confirmation.

    python experiments/laser/valve_track_trace.py --seeds 15 --dump DIR [--reach 0.3] [--config JSON] [--every]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE.parent / "estimators"), str(HERE)]

from laser_real_eval import VALVES, map_scores, parse_seeds  # noqa: E402
from pipeline_replay import light_mission, replay  # noqa: E402


def trace(seed: int, dump: Path, config: dict, reach: float, every: bool = False) -> list[str]:
    from semslam.mapping import builder, tracks
    from semslam.observations import PointObservation

    meta = light_mission(seed, {}, dump).metadata
    truth = meta.ground_truth
    valves = [(o.id, np.asarray(o.position, float)) for o in truth.objects if every or o.cls in VALVES]
    t0 = meta.extras["scans"][0]["stamp"]
    log: list[str] = []

    def near(x) -> str | None:
        for vid, p in valves:
            d = float(np.linalg.norm(np.asarray(x) - p))
            if d < reach:
                return f"{'object' if every else 'valve'} {vid} {100 * d:4.1f} cm"
        return None

    def t(stamp) -> str:
        return f"{(stamp - t0) * 1e-9:6.1f} s"

    def place(tr) -> np.ndarray:
        return tr.place if hasattr(tr, "place") else tr.mean_position()[0]

    def counts(tr) -> str:
        seen = f"{tr.seen}+{tr.seen_before}" if hasattr(tr, "seen") else "-"
        return f"views {len(tr.views)} in view {tr.in_view} seen {seen}"

    orig = {
        "extend": tracks.TrackSet.extend,
        "purge": tracks.TrackSet.purge,
        "inherit": getattr(tracks.TrackSet, "_inherit", None),
        "process": builder.MapBuilder.process,
        "merge": builder.MapBuilder.merge_duplicates,
        "confirmed": builder.MapBuilder.confirmed,
    }

    def extend(self, views, separators):
        before = {id(tr) for tr in self.tracks}
        costs = {}
        for k, v in enumerate(views):
            if isinstance(v.z, PointObservation) and near(v.position):
                costs[k] = [
                    (tr.key, float(np.linalg.norm(place(tr) - v.position)), self._cost(tr, v, separators))
                    for tr in self.tracks
                    if tr.kind == "object" and np.linalg.norm(place(tr) - v.position) < 0.3
                ]
        went, promoted = orig["extend"](self, views, separators)
        for v, tr in zip(views, went, strict=True):
            where = near(v.position) if tr.kind == "object" else None
            if where:
                new = "new " if id(tr) not in before else ""
                up = " PROMOTED" if any(tr is p for p in promoted) else ""
                log.append(f"  {t(v.stamp)} view ({where}) -> {new}track {tr.key}: {counts(tr)}{up}")
                for key, dist, cost in costs.get(views.index(v), []):
                    log.append(
                        f"      track {key} at {100 * dist:.1f} cm: cost {cost:.1f} (gate {self._gate(v.z):.1f})"
                    )
        for tr in self._retired:
            if tr.kind == "object" and near(place(tr)):
                log.append(f"  {t(views[0].stamp)} track {tr.key} forgotten as ambiguous ({near(place(tr))})")
        return went, promoted

    def purge(self, stamp):
        gone = orig["purge"](self, stamp)
        for tr in gone:
            if tr.kind == "object" and near(place(tr)) and tr not in self._retired:
                log.append(f"  {t(stamp)} track {tr.key} lapsed ({near(place(tr))}): {counts(tr)}")
        return gone

    def inherit(self, tr, v, separators):
        lapsed = {id(o): o for o in self._lapsed}
        orig["inherit"](self, tr, v, separators)
        took = [o for k, o in lapsed.items() if all(k != id(x) for x in self._lapsed)]
        for o in took:
            log.append(f"  {t(v.stamp)} track {tr.key} inherits lapsed track {o.key}: {counts(o)}")

    def process(self, stamp, observations):
        ids_before = set(self.state.objects()[0])
        obs = [z for z in observations if isinstance(z, PointObservation)]
        placed = [(z, self.state.place(z)[0]) for z in obs] if obs else []
        n_tracks = {id(v.z) for tr in self.tracks.tracks for v in tr.views}
        touched = orig["process"](self, stamp, observations)
        on_tracks = {id(v.z) for tr in self.tracks.tracks for v in tr.views} | n_tracks
        ids, pos = self.state.objects()
        for z, w in placed:
            where = near(w)
            if not where:
                continue
            if id(z) in on_tracks:
                continue  # logged by extend
            lid = [i for i in touched if i in ids_before]
            log.append(
                f"  {t(stamp)} view ({where}): not to a track (touched mapped {sorted(lid)}; "
                f"mapped objects within 0.3 m: {[int(i) for i, p in zip(ids, pos) if np.linalg.norm(p - w) < 0.3]})"
            )
        for i, p in zip(ids, pos):
            if i not in ids_before and near(p):
                log.append(f"  {t(stamp)} object {i} mapped ({near(p)})")
        return touched

    def merge(self, touched, separators=None):
        n = len(self.diagnostics)
        orig["merge"](self, touched, separators)
        for line in self.diagnostics[n:]:
            log.append(f"  {line}")

    def confirmed(self, landmarks):
        out = orig["confirmed"](self, landmarks)
        for lm in landmarks:
            if lm.kind == "object" and near(lm.position):
                kept = "kept" if lm.id not in self.left_out else "LEFT OUT"
                c = f"seen {self.in_view.seen.get(lm.id)} of in view {self.in_view.in_view.get(lm.id)}"
                log.append(f"  end: object {lm.id} ({near(lm.position)}) {kept} {c}")
        return out

    tracks.TrackSet.extend = extend
    tracks.TrackSet.purge = purge
    if orig["inherit"] is not None:  # (older map cores: no inheritance)
        tracks.TrackSet._inherit = inherit
    builder.MapBuilder.process = process
    builder.MapBuilder.merge_duplicates = merge
    builder.MapBuilder.confirmed = confirmed
    try:
        results, mission, _ = replay(seed, dump, {}, config)
    finally:
        tracks.TrackSet.extend = orig["extend"]
        tracks.TrackSet.purge = orig["purge"]
        if orig["inherit"] is not None:
            tracks.TrackSet._inherit = orig["inherit"]
        builder.MapBuilder.process = orig["process"]
        builder.MapBuilder.merge_duplicates = orig["merge"]
        builder.MapBuilder.confirmed = orig["confirmed"]
    sc = map_scores(results["graph"].landmarks, truth, meta.extras["scans"])
    head = (
        f"seed {seed}: valves once {sc['valves_mapped_once']}/{sc['valves_seen']} {sc['valve_counts']}, "
        f"objects {sc['objects_mapped']} ({sc['objects_far_from_any_fitting']} far), "
        f"within 5 cm {sc['pipe_within_5cm_share']:.3f}; valves at {[(v, np.round(p, 2).tolist()) for v, p in valves]}"
    )
    return [head, *log]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--dump", required=True, help="directory (may hold {seed})")
    ap.add_argument("--reach", type=float, default=0.3)
    ap.add_argument("--config", default="{}", help="semslam configuration overrides (JSON)")
    ap.add_argument("--every", action="store_true", help="every true object (sockets, tees...), not the valves only")
    args = ap.parse_args()
    for seed in parse_seeds(args.seeds):
        print(
            "\n".join(trace(seed, Path(args.dump.format(seed=seed)), json.loads(args.config), args.reach, args.every))
        )


if __name__ == "__main__":
    main()
