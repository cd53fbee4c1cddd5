"""The mission check, before any estimation: shared by ``info``, ``run``, ``compare`` and ``study``.

``check_mission(mission, frontends, allow_missing)`` looks only at what opening the bag already
found (the binding, the index's message counts, the sidecar), so it costs nothing:

* **no velocity source** (a DVL with messages, or the ``odometry`` front-end among those that will
  run) or **no attitude source** (an AHRS with messages): a refusal, unless the user accepts it
  (``allow_missing={"dvl"}``, ``{"ahrs"}``; the CLI's ``--allow-missing dvl,ahrs``), then a warning;
* **no depth sensor**: a warning (the vertical position is not measured);
* **no extrinsics** for a bag's sensor (neither ``reader.sensors.<name>.T_BS`` nor the sidecar gives
  one): a warning naming the sensors whose identity mount is assumed, and the key that gives them;
* a sensor the sidecar declares but the bag does not hold: a warning (it is not read).

What needs the messages is found while they stream (``semslam.mission.clock_guard``): clock resets,
interleaved recordings and repeated stamps raise a ``MissionError`` there, at once, unless the
mission is read with ``reader.on_clock_jump: split``; ``stream_findings(mission)`` lists them after
a pass, with the messages dropped for their stamps (``semslam info`` reads in survey mode, which
records instead of raising). ``input_block(mission)`` is ``metrics.json``'s ``input`` and
``input_line(mission)`` the line a run prints about it.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field

from semslam.errors import ConfigError, MissionError
from semslam.mission.clock_guard import STAMP_REASONS
from semslam.mission.mission import Mission
from semslam.mission.sidecar import sidecar_path

VELOCITY_FRONTENDS = frozenset({"odometry"})  # front-ends whose observations give the vehicle's motion
# What --allow-missing accepts: sensor kind → what is missing without it.
ALLOWABLE = {"dvl": "velocity", "ahrs": "attitude"}
# What a run without the source gives, said when it is accepted (--allow-missing).
CONSEQUENCE = {
    "dvl": "the horizontal position drifts without bound",
    "ahrs": "the attitude is not measured: an estimator that starts on an AHRS reading gives no trajectory, "
    "one started from a ground-truth pose drifts in attitude",
}
NO_GROUND_TRUTH_MOUNT = frozenset({"ground_truth"})  # kinds whose T_BS means nothing


@dataclass(frozen=True)
class Finding:
    severity: str  # "refusal" | "warning" | "note"
    text: str  # one line, without the mission's path


@dataclass
class MissionCheck:
    """What the check found about one mission (``where``: its bag path, else its name)."""

    where: str
    findings: list[Finding] = field(default_factory=list)

    @property
    def refusals(self) -> list[str]:
        return [f.text for f in self.findings if f.severity == "refusal"]

    @property
    def warnings(self) -> list[str]:
        """One line each, naming the mission: what a command prints on stderr before it runs."""
        return [f"{self.where}: {f.text}" for f in self.findings if f.severity == "warning"]

    def raise_if_refused(self) -> None:
        """A MissionError (one line: the first refusal, and how many more) if anything is refused."""
        refused = self.refusals
        if refused:
            more = f" (and {len(refused) - 1} more, listed by semslam info)" if len(refused) > 1 else ""
            raise MissionError(f"{self.where}: {refused[0]}{more}")

    def lines(self) -> list[str]:
        """The ``check:`` section of ``semslam info``."""
        if not self.findings:
            return ["check: nothing refused, nothing to warn about"]
        label = {"refusal": "refused", "warning": "warning", "note": "note"}
        return ["check:"] + [f"  {label[f.severity]}: {f.text}" for f in self.findings]


def parse_allow_missing(text: str | Collection[str] | None) -> frozenset[str]:
    """``"dvl,ahrs"`` (the CLI's ``--allow-missing``) or a collection → the set; an unknown name is a
    ConfigError naming it."""
    items = text.split(",") if isinstance(text, str) else (text or ())
    names = frozenset(n.strip() for n in items if n.strip())
    unknown = sorted(names - set(ALLOWABLE))
    if unknown:
        raise ConfigError(f"--allow-missing: unknown sensor kind {unknown[0]!r} (expected {', '.join(ALLOWABLE)})")
    return names


def where(mission: Mission) -> str:
    return mission.label or str(getattr(mission, "path", "") or f"mission {mission.metadata.name}")


def check_mission(
    mission: Mission, frontends: Collection[str] = (), allow_missing: str | Collection[str] | None = ()
) -> MissionCheck:
    """The check before any estimation (see the module docstring); ``frontends``: the names of the
    front-ends that will run. Reads no message."""
    allowed = parse_allow_missing(allow_missing)
    out = MissionCheck(where(mission))
    found = out.findings.append
    if not VELOCITY_FRONTENDS & set(frontends):
        _source(mission, "dvl", "DVL", allowed, found)
    _source(mission, "ahrs", "AHRS", allowed, found)
    if not _present(mission, "depth"):
        found(Finding("warning", "no depth sensor: the vertical position is not measured and drifts"))
    plan = getattr(mission, "plan", None)
    if plan is None:
        return out
    meta = mission.metadata
    assumed = [
        s
        for s, how in plan.extrinsics.items()
        if how == "assumed" and meta.sensors[s].kind not in NO_GROUND_TRUTH_MOUNT
    ]
    if assumed:
        side = "not in the sidecar" if sidecar_path(mission.path).exists() else "no sidecar"
        found(
            Finding(
                "warning",
                f"no extrinsics for {', '.join(assumed)} ({side}): identity mounts assumed (each sensor at the "
                "body origin, axes along the body's); give them as reader.sensors.<name>.T_BS "
                "(semslam info --write-config F writes the binding to fill in)",
            )
        )
    others = [a for a in plan.binding.absent if a.kind not in ALLOWABLE]
    if others:
        listed = ", ".join(f"{a.sensor} ({a.topic})" for a in others)
        found(Finding("warning", f"the sidecar's sensor(s) {listed} not in the bag: not read"))
    return out


def _present(mission: Mission, kind: str) -> bool:
    counts = getattr(mission, "message_counts", None)
    sensors = mission.metadata.sensors_of_kind(kind)
    return any(counts is None or counts.get(s.topic, 0) > 0 for s in sensors)


def _source(mission: Mission, kind: str, what: str, allowed: frozenset[str], found) -> None:
    if _present(mission, kind):
        return
    need = ALLOWABLE[kind]
    why = _why_missing(mission, kind, what)
    if kind in allowed:
        found(Finding("warning", f"no {need} source ({why}): accepted (--allow-missing {kind}); {CONSEQUENCE[kind]}"))
        return
    velocity = " and no odometry front-end" if kind == "dvl" else ""
    found(
        Finding(
            "refusal",
            f"no {need} source ({why}{velocity}): no estimator gives a meaningful trajectory without "
            f"one (bind a topic in reader.sensors with kind {kind}, or accept it with --allow-missing {kind})",
        )
    )


def _why_missing(mission: Mission, kind: str, what: str) -> str:
    plan = getattr(mission, "plan", None)
    empty = [s.topic for s in mission.metadata.sensors_of_kind(kind)]
    if empty:
        return f"the {what} topic {', '.join(empty)} holds no message"
    if plan is not None:
        absent = [a for a in plan.binding.absent if a.kind == kind]
        if absent:
            return f"the sidecar's {what} {absent[0].sensor!r} on {absent[0].topic} is not in the bag"
        unread = [f"{u.topic}: {u.reason}" for u in plan.binding.alternatives(kind)]
        if unread:
            return f"no usable {what} topic: {'; '.join(unread)}"
    return f"no {what} topic"


def stream_findings(mission: Mission) -> list[Finding]:
    """After a complete pass over a bag: its clock problems (refusals, unless split reads a part of a
    reset mission) and the messages dropped for their stamps, with the mission time of the first."""
    rest = mission.rest
    assumed = [Finding("warning", rest.describe())] if rest is not None and rest.said else []
    problems = getattr(mission, "clock_problems", [])
    if not problems and not getattr(mission, "first_dropped", None):
        return assumed
    cfg = mission.config
    out = assumed
    for p in problems:
        split = p.splittable and cfg.on_clock_jump == "split"
        out.append(Finding("warning" if split else "refusal", p.describe(hint=not split)))
    segments = getattr(mission, "segments", [])
    if len(segments) > 1:  # what reader.segment chooses from
        split = cfg.on_clock_jump == "split"
        parts = "; ".join(
            f"{k + 1}: {s.count} messages over {(s.last - s.first) * 1e-9:.3f} s"
            + (" (read)" if k + 1 == (cfg.segment if split else 1) else "")
            for k, s in enumerate(segments)
            if s.first is not None
        )
        read = f"read part {cfg.segment} (reader.segment)" if split else "parts that split would read"
        out.append(Finding("warning" if split else "note", f"{read}: {parts}"))
    start = getattr(mission, "recording_start", None) or 0
    for sensor, firsts in getattr(mission, "first_dropped", {}).items():
        fields = mission.dropped_fields.get(sensor, {})
        for reason in STAMP_REASONS:
            if reason in firsts:
                out.append(
                    Finding(
                        "warning",
                        f"{sensor}: {fields[reason]} message(s) dropped: {reason} (the first at mission time "
                        f"{(firsts[reason] - start) * 1e-9:.3f} s)",
                    )
                )
    return out


def input_block(mission: Mission) -> dict:
    """``metrics.json``'s ``input`` after a complete pass: ``{"dropped": {sensor: n}, "invalid":
    {sensor: n}}`` over every sensor (0 included); ``dropped``: messages never passed on (non-finite,
    unusable, stamps out of order, GPS below the surface), ``invalid``: readings the sensor flagged
    invalid (DVL dropouts), passed on as such. A mission read in parts adds ``"segment": k``."""
    names = list(mission.metadata.sensors)
    names += sorted((set(mission.dropped) | set(mission.invalid)) - set(names))
    block = {
        "dropped": {n: int(mission.dropped.get(n, 0)) for n in names},
        "invalid": {n: int(mission.invalid.get(n, 0)) for n in names},
    }
    cfg = getattr(mission, "config", None)
    if cfg is not None and cfg.on_clock_jump == "split":
        block["segment"] = cfg.segment
    rest = mission.rest
    if rest is not None and rest.held_said:
        block["at_rest_s"] = round(rest.held_s, 3)
    if rest is not None and rest.still_said:
        block["still_s"] = round(rest.still_s, 3)
    return block


def input_line(mission: Mission) -> str:
    """One line for a run's summary: what was dropped (and why) and what was invalid, per sensor."""
    why = getattr(mission, "dropped_fields", {})
    dropped = [
        f"{n} {k}" + (f" ({', '.join(f'{r} ×{c}' for r, c in why[n].items())})" if why.get(n) else "")
        for n, k in mission.dropped.items()
        if k
    ]
    invalid = [f"{n} {k}" for n, k in mission.invalid.items() if k]
    text = "dropped " + ", ".join(dropped) if dropped else "no message dropped"
    text += "; invalid " + ", ".join(invalid) if invalid else ", no invalid reading"
    return f"input: {text}"
