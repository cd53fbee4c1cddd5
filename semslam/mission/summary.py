"""What ``semslam info`` prints: per-sensor counts, rates, time span, DVL dropouts, gaps, drops,
and, for a bag, how it was read: the surface pressure and GPS datum found, the clock offset, each
sensor's stamp source, the topic chosen per sensor and why every other topic was left unread,
what was assumed (covariances a message left unknown) and what looks wrong (a cloud's scale).

A gap is an interval between consecutive messages of a stream longer than ``GAP_FACTOR`` times the
stream's median period; for a DVL, the interval between consecutive *valid* readings (a dropout:
bottom lock lost, or the DVL silent). Times in the table are seconds from the mission start.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone

import numpy as np

from semslam.mission.conversions import short_msgtype
from semslam.mission.measurements import DvlVelocity
from semslam.mission.mission import Mission, SensorStats

GAP_FACTOR = 3.0
MAX_GAPS_LISTED = 10


@dataclass
class SensorSummary:
    name: str
    kind: str
    topic: str | None
    msgtype: str | None
    stats: SensorStats
    dropped_fields: dict[str, int] = field(default_factory=dict)
    period_s: float | None = None  # median period of the stream


@dataclass
class MissionSummary:
    name: str
    source: str | None  # the bag path, when read from one
    sensors: list[SensorSummary]
    start: int | None  # first stamp over all sensors (ns)
    end: int | None
    reading: list[str] = field(default_factory=list)  # how the bag was read (see reading_report)

    @property
    def duration_s(self) -> float:
        return 0.0 if self.start is None else (self.end - self.start) * 1e-9

    @property
    def count(self) -> int:
        return sum(s.stats.count for s in self.sensors)

    @property
    def dropped(self) -> int:
        return sum(s.stats.dropped_nonfinite for s in self.sensors)

    def sensor(self, name: str) -> SensorSummary:
        return next(s for s in self.sensors if s.name == name)

    def format(self) -> str:
        """A readable report: header, one table row per sensor, then gaps and dropped messages."""
        lines = [f"mission {self.name}" + (f"  ({self.source})" if self.source else "")]
        if self.start is None:
            lines.append("no measurements")
        else:
            utc = datetime.fromtimestamp(self.start * 1e-9, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
            lines.append(
                f"start {self.start * 1e-9:.3f} s ({utc})   duration {self.duration_s:.3f} s   "
                f"measurements {self.count}   dropped {self.dropped}"
            )
        lines.append("")
        header = (
            "sensor",
            "kind",
            "topic",
            "message type",
            "count",
            "rate Hz",
            "first s",
            "last s",
            "duration s",
            "invalid",
            "dropped",
            "max gap s",
        )
        rows = [header]
        t0 = self.start or 0
        for s in self.sensors:
            st = s.stats
            span = None if st.first is None else (st.last - st.first) * 1e-9
            rows.append(
                (
                    s.name,
                    s.kind,
                    s.topic or "-",
                    short_msgtype(s.msgtype) if s.msgtype else "-",
                    str(st.count),
                    "-" if st.rate_hz is None else f"{st.rate_hz:.2f}",
                    "-" if st.first is None else f"{(st.first - t0) * 1e-9:.3f}",
                    "-" if st.last is None else f"{(st.last - t0) * 1e-9:.3f}",
                    "-" if span is None else f"{span:.3f}",
                    str(st.invalid) if s.kind == "dvl" else "-",
                    str(st.dropped_nonfinite),
                    f"{st.max_gap_s:.3f}",
                )
            )
        widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
        numeric = set(range(4, len(header)))
        for r in rows:
            cells = (c.rjust(w) if i in numeric else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths)))
            lines.append("  ".join(cells).rstrip())
        gap_lines = []
        for s in self.sensors:
            what = "DVL dropout" if s.kind == "dvl" else "gap"
            period = f" (period {s.period_s:.3f} s)" if s.period_s else ""
            for start, dur in s.stats.gaps[:MAX_GAPS_LISTED]:
                gap_lines.append(f"  {s.name}: {what} at {start:.3f} s for {dur:.3f} s{period}")
            if len(s.stats.gaps) > MAX_GAPS_LISTED:
                gap_lines.append(f"  {s.name}: ... {len(s.stats.gaps) - MAX_GAPS_LISTED} more")
        if gap_lines:
            lines += [
                "",
                f"gaps (longer than {GAP_FACTOR:g}× the stream's median period; DVL: between valid readings):",
            ]
            lines += gap_lines
        drop_lines = [
            f"  {s.name}: {s.stats.dropped_nonfinite} message(s) dropped"
            + (
                f" (non-finite or unusable field: {', '.join(f'{k} ×{v}' for k, v in s.dropped_fields.items())})"
                if s.dropped_fields
                else " (non-finite)"
            )
            for s in self.sensors
            if s.stats.dropped_nonfinite
        ]
        if drop_lines:
            lines += ["", "dropped messages (never passed on):"] + drop_lines
        if self.reading:
            lines += [""] + self.reading
        return "\n".join(lines) + "\n"


def _gaps(
    stamps: np.ndarray, valid: np.ndarray | None, t0: int
) -> tuple[list[tuple[float, float]], float, float | None]:
    """(gaps as (start s from t0, duration s), max gap s, median period s) of one stream."""
    if stamps.size < 2:
        return [], 0.0, None
    period = float(np.median(np.diff(stamps))) * 1e-9
    if valid is not None:
        # Dropouts are measured between valid readings; the stream's ends bound leading/trailing runs.
        stamps = np.concatenate([stamps[:1], stamps[valid], stamps[-1:]])
    d = np.diff(stamps) * 1e-9
    max_gap = float(d.max()) if d.size else 0.0
    if period <= 0:
        return [], max_gap, None
    big = np.flatnonzero(d > GAP_FACTOR * period)
    return [((int(stamps[i]) - t0) * 1e-9, float(d[i])) for i in big], max_gap, period


def summarize(mission: Mission, progress: bool = False) -> MissionSummary:
    """One pass over ``mission``: per-sensor statistics (see ``MissionSummary``).

    ``progress`` shows a tqdm bar on stderr (its total is the bag's message count when known).
    """
    from tqdm import tqdm

    stamps: dict[str, list[int]] = {}
    valid: dict[str, list[bool]] = {}
    it = tqdm(
        mission,
        total=getattr(mission, "message_count", None),
        disable=not progress,
        unit="msg",
        desc=f"reading {mission.metadata.name}",
        leave=False,
    )
    for m in it:
        stamps.setdefault(m.sensor, []).append(m.stamp)
        if isinstance(m, DvlVelocity):
            valid.setdefault(m.sensor, []).append(m.valid)

    names = list(mission.metadata.sensors) + sorted(set(stamps) - set(mission.metadata.sensors))
    names += sorted(set(mission.dropped) - set(names))
    firsts = [s[0] for s in stamps.values() if s]
    t0 = min(firsts) if firsts else None
    t1 = max(s[-1] for s in stamps.values() if s) if firsts else None
    dropped_fields = getattr(mission, "dropped_fields", {})
    out = []
    for name in names:
        info = mission.metadata.sensors.get(name)
        ts = np.asarray(stamps.get(name, []), dtype=np.int64)
        v = np.asarray(valid[name], dtype=bool) if name in valid else None
        kind = info.kind if info else ("dvl" if v is not None else "?")
        gaps, max_gap, period = _gaps(ts, v, t0 or 0)
        st = SensorStats(
            count=int(ts.size),
            first=int(ts[0]) if ts.size else None,
            last=int(ts[-1]) if ts.size else None,
            dropped_nonfinite=int(mission.dropped.get(name, 0)),
            invalid=int((~v).sum()) if v is not None else 0,
            max_gap_s=max_gap,
            gaps=gaps,
        )
        out.append(
            SensorSummary(
                name=name,
                kind=kind,
                topic=info.topic if info else None,
                msgtype=info.msgtype if info else None,
                stats=st,
                dropped_fields=dict(dropped_fields.get(name, {})),
                period_s=period,
            )
        )
    source = str(getattr(mission, "path", "")) or None
    return MissionSummary(
        name=mission.metadata.name, source=source, sensors=out, start=t0, end=t1, reading=reading_report(mission)
    )


def _counted(counts: dict[str, int]) -> str:
    return ", ".join(f"{what} ×{n}" for what, n in counts.items())


def reading_report(mission: Mission) -> list[str]:
    """How a bag mission was read (empty for other missions); after a full pass over it."""
    plan = getattr(mission, "plan", None)
    if plan is None:
        return []
    meta = mission.metadata
    gt = "none (a real recording: nothing is compared against truth)"
    if meta.ground_truth is not None or meta.sensors_of_kind("ground_truth"):
        topics = ", ".join(s.topic or s.name for s in meta.sensors_of_kind("ground_truth")) or "no trajectory"
        gt = f"from the mission's sidecar and {topics}"
    lines = ["reading:", f"  ground truth: {gt}"]
    lines.append(f"  atmospheric pressure: {plan.atmosphere.value:.0f} Pa ({plan.atmosphere.how})")
    if plan.datum.value is not None:
        lines.append(f"  GPS datum: {plan.datum.value.format()} ({plan.datum.how})")
    lines.append(f"  clock: {plan.clock.format()}")
    lines += ["", f"time stamps (reader.stamp: {mission.config.stamp}):"]
    for b in plan.binding.bindings:
        c = plan.stamps[b.sensor]
        source = "header stamp" if c.source == "header" else "receive time + offset"
        lines.append(f"  {b.sensor}: {source} ({c.policy}: {c.reason})")
    origin = {"configured": "reader.sensors", "sidecar": "the mission's sidecar", "chosen": "chosen by the rule"}
    lines += ["", "binding (topic → sensor):"]
    for b in plan.binding.bindings:
        others = [u.topic for u in plan.binding.alternatives(b.kind)]
        alt = f"; alternatives: {', '.join(others)}" if others and b.origin == "chosen" else ""
        lines.append(f"  {b.topic} → {b.sensor} ({short_msgtype(b.msgtype)}, {origin[b.origin]}{alt})")
    if plan.binding.unread:
        lines += ["", "unread topics (never read nor checked):"]
        width = max(len(u.topic) for u in plan.binding.unread)
        for u in plan.binding.unread:
            lines.append(f"  {u.topic.ljust(width)}  {u.msgtype or '-'}: {u.reason}")
    notes = getattr(mission, "notes", {})
    if notes:
        lines += ["", "assumed (messages left it unknown):"]
        lines += [f"  {sensor}: {_counted(c)}" for sensor, c in notes.items()]
    warnings = [f"  {sensor}: {_counted(c)}" for sensor, c in getattr(mission, "warnings", {}).items()]
    warnings += [
        f"  {what}: {r.warning}" for what, r in (("atmosphere", plan.atmosphere), ("GPS", plan.datum)) if r.warning
    ]
    if warnings:
        lines += ["", "warnings:"] + warnings
    return lines
