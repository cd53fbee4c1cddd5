"""Which clock stamps each sensor's measurements: the stamp policy ``reader.stamp``.

The mission clock is the header clock (the vehicle's, usually). Per sensor (``reader.stamp``, or
``reader.sensors.<name>.stamp``):

* ``header``: the message's header stamp; a lone stamp of 0 (a driver that did not fill one
  message) becomes that message's receive time mapped onto the header clock.
* ``receive``: the recorder's receive time mapped onto the header clock: t_receive + offset.
* ``auto``: ``header``, except for a topic whose first messages (``semslam.mission.probe``) have
  header stamps that are all zero, constant, running backwards, or on a clock of their own (more
  than ``FOREIGN_CLOCK_S`` away from the other topics' header clock): ``receive``. What stamps
  do later in the stream (a late message, a repeat, a clock reset) is ``semslam.mission.clock_guard``'s.

The offset (header clock − receive clock) is estimated robustly from the topics that have both: per
topic, the median of header − receive over its first messages (which absorbs its latency); over
topics, the median of the largest group of topics that agree within ``FOREIGN_CLOCK_S`` (ties: the
group with more messages). The vehicle's clock may be days away from the recorder's; that is fine.
With no topic of valid header stamps, the offset is 0 and receive time is the mission clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semslam.mission.probe import TopicProbe

FOREIGN_CLOCK_S = 10.0


@dataclass(frozen=True)
class StampChoice:
    source: str  # "header" | "receive"
    policy: str  # the policy that decided it: auto | header | receive
    reason: str  # why (auto), for `semslam info`


@dataclass(frozen=True)
class ClockOffset:
    offset_ns: int  # header clock − receive clock
    topics: tuple[str, ...]  # the topics it was estimated from

    def format(self) -> str:
        if not self.topics:
            return "no topic has valid header stamps: the receive time is the mission clock (offset 0)"
        s = self.offset_ns * 1e-9
        days = f" ({s / 86400:+.2f} days)" if abs(s) >= 3600 else ""
        return (
            f"receive time → header clock: {s:+.3f} s{days}, median over {len(self.topics)} topic(s) "
            f"with both ({', '.join(self.topics)})"
        )


def header_problem(p: TopicProbe) -> str | None:
    """Why a topic's header stamps cannot be the mission clock, from its first messages; None if they can."""
    h = p.header
    if not h:
        return None
    if not any(h):
        return "header stamps are all zero"
    if len(h) >= 2 and len(set(h)) == 1:
        return "header stamps are constant"
    nonzero = [x for x in h if x]
    if any(b < a for a, b in zip(nonzero, nonzero[1:])):
        return "header stamps run backwards"
    return None


def _topic_offset(p: TopicProbe) -> int:
    return int(np.median([h - r for h, r in zip(p.header, p.receive) if h]))


def estimate_offset(probes: dict[str, TopicProbe]) -> tuple[ClockOffset, dict[str, str]]:
    """The clock offset, and the topics whose header clock is foreign (topic → reason)."""
    offsets = {t: _topic_offset(p) for t, p in sorted(probes.items()) if p.n and header_problem(p) is None}
    if not offsets:
        return ClockOffset(0, ()), {}
    tol = int(FOREIGN_CLOCK_S * 1e9)

    def group(t: str) -> list[str]:
        return [u for u in offsets if abs(offsets[u] - offsets[t]) <= tol]

    best = max(offsets, key=lambda t: (len(group(t)), sum(probes[u].n for u in group(t))))
    members = group(best)
    offset = int(np.median([offsets[u] for u in members]))
    foreign = {
        t: f"header clock {(offsets[t] - offset) * 1e-9:+.1f} s away from the other topics'"
        for t in offsets
        if t not in members
    }
    return ClockOffset(offset, tuple(members)), foreign


def choose_stamp(policy: str, probe: TopicProbe | None, foreign: str | None) -> StampChoice:
    """The stamp source of one topic under ``policy``."""
    if policy == "header":
        return StampChoice("header", policy, "configured")
    if policy == "receive":
        return StampChoice("receive", policy, "configured")
    problem = (header_problem(probe) if probe is not None else None) or foreign
    if problem:
        return StampChoice("receive", policy, problem)
    return StampChoice("header", policy, "valid header stamps")
