"""Stamp order per topic while a bag streams: late messages, repeated stamps, clock jumps and
interleaved recordings, found in the stream itself (no pass of their own).

Per topic, in the order the bag is read (the recorder's receive time), for header-stamped topics:

* A header stamp up to ``reader.clock_jump_s`` before the topic's previous one is one late message;
  the same stamp again is a repeat (a byte-identical message: a duplicate). Both are dropped and
  counted (``semslam info`` lists them, with the time of the first). With ``stamp: header`` for that
  topic, a late or repeated stamp is an error.
* A header stamp further back is a **clock jump** when the topic's next message goes on from it (else
  it was one wild stamp: dropped and counted). Jumps on every header-stamped topic within a few of
  their periods (``grace``) are a **clock reset** of the mission: ``reader.on_clock_jump: error``
  refuses it; ``split`` reads one part of it (``reader.segment``: 1 = up to the first reset, 2 = from
  it to the next, ...), the topics read by receive time moved by the clock's change. Whether the
  recorder's clock ran on is said, since then ``reader.stamp: receive`` reads the mission as one.
  A jump on some topics only (a sensor's own clock) is refused either way, naming them: read them by
  receive time.
* **Interleaved**: when the recorder's clock went back with the vehicle's (one computer, one clock
  step), the bag, read in receive-time order, mixes two stretches of the same times: every topic of
  regular rate comes at about twice its rate, or repeats its stamps. Refused: no order in the bag
  tells the two stretches apart. (Looked for on the topics whose first messages came at a regular
  rate of at least 1 Hz, when there are two or more.)
* **Repeats**: a topic whose stamps repeat (different messages, one stamp) ``REPEATS_MIN`` times in
  ``WINDOW`` messages has a coarse or stalled clock: refused; read it by receive time.

``survey`` (``semslam info``) records the problems instead of raising them, reads to the end and
counts every part.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from semslam.errors import MissionError
from semslam.mission.config import ReaderConfig

BACKWARDS = "header stamp runs backwards"
REPEATED = "header stamp repeats the previous one"
DUPLICATE = "duplicate message"
STAMP_REASONS = (BACKWARDS, REPEATED, DUPLICATE)
WINDOW = 16  # a topic's last messages, looked at for crowding and repeats
CROWDED = 0.6  # an interval shorter than this fraction of the topic's period is crowded
CROWDED_MIN = 6  # crowded intervals in WINDOW that flag a topic (interleaved: every other one is)
REPEATS_MIN = 3  # repeated stamps in WINDOW that flag a topic
REGULAR_PROBE_MIN = 16  # first messages needed to call a topic's rate regular
S = 1_000_000_000


@dataclass(frozen=True)
class TopicClock:
    """What the guard knows of one bound topic."""

    sensor: str
    source: str  # header | receive
    strict: bool  # stamp policy header: a late or repeated stamp is an error
    period_ns: int | None = None  # its regular period (see regular_period), None if irregular or unknown


def regular_period(header: list[int]) -> int | None:
    """The period (ns) of a topic whose first header stamps come at a regular rate of at least 1 Hz
    (80% of the intervals within 25% of the median), else None."""
    h = np.asarray([x for x in header if x], dtype=np.int64)
    if h.size < REGULAR_PROBE_MIN:
        return None
    d = np.diff(h)
    p = float(np.median(d))
    if not 0 < p <= S or np.mean(np.abs(d - p) <= 0.25 * p) < 0.8:
        return None
    return int(p)


@dataclass(frozen=True)
class ClockProblem:
    """A clock problem found in the stream (see the module docstring)."""

    kind: str  # reset | partial | interleaved | repeats
    stamp_ns: int  # the last stamp before a jump; the first crowded or repeated stamp
    at_s: float  # its mission time: seconds from the recording's first stamp
    topics: tuple[str, ...]
    sensors: tuple[str, ...]  # the sensors of ``topics``
    back_s: float = 0.0  # reset, partial: how far the header stamps went back
    receive_ran_on: bool = False  # reset: the recorder's clock did not jump with the header stamps
    others: tuple[str, ...] = ()  # partial: the header-stamped topics that did not jump

    @property
    def splittable(self) -> bool:
        return self.kind == "reset"

    def describe(self, hint: bool = True) -> str:
        """One line (without the bag's path); ``hint`` adds what the user can do."""
        where = f"at mission time {self.at_s:.3f} s (stamp {self.stamp_ns * 1e-9:.6f} s)"
        tops = ", ".join(self.topics)
        by_receive = f"read {', '.join(self.sensors)} by receive time (reader.sensors.<name>.stamp: receive)"
        if self.kind == "reset":
            text = f"clock reset {where}: the header stamps of {tops} went back {self.back_s:.3f} s at once"
            if hint:
                ran_on = "reader.stamp: receive reads the mission as one (the recorder's clock ran on); "
                text += (
                    f"; {ran_on if self.receive_ran_on else ''}reader.on_clock_jump: split reads one part "
                    "(reader.segment: 1 before it, 2 after it)"
                )
            return text
        if self.kind == "partial":
            text = (
                f"clock jump {where}: the header stamps of {tops} went back {self.back_s:.3f} s, those of "
                f"{', '.join(self.others)} did not (a sensor's own clock?)"
            )
            return text + (f"; {by_receive}" if hint else "")
        if self.kind == "interleaved":
            text = (
                f"interleaved recording from mission time {self.at_s:.3f} s: {tops} come at twice their rate or "
                "repeat their stamps, two stretches of the mission with the same times (the recorder's clock "
                "went back with the vehicle's? two recordings merged?)"
            )
            return text + ("; the bag does not tell them apart, so it cannot be split" if hint else "")
        text = f"different messages with the same header stamp on {tops} {where}: a coarse or stalled clock"
        return text + (f"; {by_receive}" if hint else "")


@dataclass
class Segment:
    """One part of a recording between clock resets: its messages and stamp span (on its own clock)."""

    count: int = 0
    first: int | None = None
    last: int | None = None


@dataclass
class _Jump:
    t_bag: int  # receive time of the first topic's jump
    before: int  # that topic's last stamp before it
    back: int  # how far its stamps went back
    change: int  # the header clock's change against the receive clock (what it went back when the recorder's ran on)
    topics: list[str] = field(default_factory=list)


class _Topic:
    """The guard's state of one topic."""

    def __init__(self, topic: str, clock: TopicClock):
        self.topic = topic
        self.clock = clock
        self.crowd_ns = int(CROWDED * clock.period_ns) if clock.period_ns else -1  # a shorter interval is crowded
        self.last: int | None = None  # the last stamp taken, in this epoch
        self.last_tbag = 0
        self.last_raw = None
        self.seen_tbag: int | None = None  # receive time of its latest message, whatever became of it
        self.epoch = 0  # clock jumps it went through
        self.suspect: tuple | None = None  # (t_bag, stamp, raw, item): a stamp far back, pending its next message
        self.window: deque[tuple[int, int]] = deque(maxlen=WINDOW)  # (flags: 1 crowded | 2 repeat, stamp)
        self.crowded = 0
        self.repeats = 0
        self.flagged = False
        self.repeating: int | None = None  # when flagged for repeats: the first repeated stamp in its window

    def note(self, flags: int, stamp: int) -> bool:
        """Slide the window on by one message; True if its counts grew."""
        w = self.window
        if len(w) == WINDOW:
            old = w[0][0]
            if old:
                self.crowded -= old & 1
                self.repeats -= old >> 1
        w.append((flags, stamp))
        if not flags:
            return False
        self.crowded += flags & 1
        self.repeats += flags >> 1
        return True

    def clear_window(self) -> None:
        self.window.clear()
        self.crowded = self.repeats = 0
        self.flagged = False
        self.repeating = None


class StampGuard:
    """Admits a bag's messages, topic by topic, in the order they are read (see the module docstring).

    ``admit`` returns the items to go on with, each with its mission-clock stamp: only those of the
    part read (``reader.segment`` with ``split``, else the first); ``finish`` settles what is pending
    at the end. Drops are counted into ``dropped`` (sensor → count) and ``fields`` (sensor → reason →
    count), shared with the caller; ``first_drop`` keeps the first stamp per sensor and reason.
    """

    def __init__(
        self,
        path,
        clocks: dict[str, TopicClock],
        offset_ns: int,
        cfg: ReaderConfig,
        ros_version: int,
        dropped: Counter[str],
        fields: dict[str, Counter[str]],
        survey: bool = False,
    ):
        self.path = path
        self.offset = offset_ns
        self.jump = int(cfg.clock_jump_s * S)
        self.split = cfg.on_clock_jump == "split"
        self.want = cfg.segment - 1 if self.split else 0
        self.skip = 4 if ros_version == 1 else 0  # a ROS 1 header's seq differs between duplicates
        self.survey = survey
        self.dropped = dropped
        self.fields = fields
        self.first_drop: dict[str, dict[str, int]] = {}
        self.problems: list[ClockProblem] = []
        self.segments: list[Segment] = [Segment()]
        self._topics = {t: _Topic(t, c) for t, c in clocks.items()}
        periods = [c.period_ns or S for c in clocks.values() if c.source == "header"]
        # Long enough for every header-stamped topic to show its jump and the message after it.
        self.grace = max(2 * S, int(2.5 * max(periods, default=S)))
        self._open: _Jump | None = None
        self._shifts: list[tuple[int, int]] = []  # (receive time, clock change) of each reset
        self._crowd_since: int | None = None
        self._interleaved = False
        self._reported: set[tuple[str, str]] = set()

    # -- the stream's side ---------------------------------------------------------------------
    def admit(self, topic: str, t_bag: int, header_stamp: int, raw, item) -> list[tuple[object, int]]:
        st = self._topics[topic]
        st.seen_tbag = t_bag
        if self._open is not None or self._crowd_since is not None:
            self._expire(t_bag)
        if st.clock.source == "receive":
            epoch, shift = self._receive_clock(t_bag)
            return self._take(st, epoch, t_bag + self.offset + shift, t_bag, raw, item, ordered=False)
        stamp = header_stamp or t_bag + self.offset + self._receive_clock(t_bag)[1]  # a lone zero: receive time
        out = self._settle(st, stamp) if st.suspect is not None else None
        last = st.last
        if last is not None and stamp <= last:
            if stamp < last - self.jump:
                st.suspect = (t_bag, stamp, raw, item)
            elif stamp < last:
                self._late(st, stamp, BACKWARDS)
            elif st.last_raw is not None and memoryview(raw)[self.skip :] == memoryview(st.last_raw)[self.skip :]:
                self._drop(st, DUPLICATE, stamp)
            else:
                self._late(st, stamp, REPEATED)
                self._note(st, 3, t_bag, stamp)
            return out or []
        taken = self._take(st, st.epoch, stamp, t_bag, raw, item)
        return out + taken if out else taken

    @property
    def done(self) -> bool:
        """Split: every header-stamped topic is past the part read (the rest of the bag is not needed)."""
        if not self.split or self.survey or self._open is not None or len(self._shifts) <= self.want:
            return False
        seen = [st for st in self._topics.values() if st.clock.source == "header" and st.seen_tbag is not None]
        return bool(seen) and all(st.epoch > self.want for st in seen)

    def finish(self) -> None:
        for st in self._topics.values():
            if st.suspect is not None:  # a wild stamp at the very end
                _, stamp, _, _ = st.suspect
                st.suspect = None
                self._late(st, stamp, BACKWARDS)
        if self._open is not None:
            self._close(self._open)
        if self._crowd_since is not None:
            self._settle_crowding()
        if self.split and self.want >= len(self.segments):
            resets = ", ".join(f"{p.at_s:.3f} s" for p in self.problems if p.kind == "reset")
            raise MissionError(
                f"{self.path}: reader.segment: {self.want + 1}, but the recording has {len(self.segments)} "
                f"part(s)" + (f" (clock resets at {resets})" if resets else " (no clock reset)")
            )

    # -- stamps --------------------------------------------------------------------------------
    def _take(self, st: _Topic, epoch: int, stamp: int, t_bag: int, raw, item, ordered: bool = True):
        if ordered and st.last is not None:
            self._note(st, 1 if stamp - st.last <= st.crowd_ns else 0, t_bag, stamp)
        st.last, st.last_tbag, st.last_raw = stamp, t_bag, raw
        while len(self.segments) <= epoch:
            self.segments.append(Segment())
        seg = self.segments[epoch]
        seg.count += 1
        if seg.first is None or stamp < seg.first:
            seg.first = stamp
        if seg.last is None or stamp > seg.last:
            seg.last = stamp
        return [(item, stamp)] if epoch == self.want else []

    @property
    def start(self) -> int | None:
        """The recording's first stamp: mission time 0."""
        return self.segments[0].first

    def _late(self, st: _Topic, stamp: int, reason: str) -> None:
        if st.clock.strict:
            what = (
                f"header stamps go backwards ({stamp * 1e-9:.6f} s after {st.last * 1e-9:.6f} s)"
                if reason == BACKWARDS
                else f"header stamp {stamp * 1e-9:.6f} s repeats the previous message's"
            )
            raise MissionError(f"{self.path}: topic {st.topic}: {what}")
        self._drop(st, reason, stamp)

    def _drop(self, st: _Topic, reason: str, stamp: int) -> None:
        sensor = st.clock.sensor
        self.dropped[sensor] += 1
        self.fields[sensor][reason] += 1
        self.first_drop.setdefault(sensor, {}).setdefault(reason, stamp)

    def _at(self, stamp: int) -> float:
        return (stamp - (self.start if self.start is not None else stamp)) * 1e-9

    def _receive_clock(self, t_bag: int) -> tuple[int, int]:
        """(epoch, clock change) of a message received at ``t_bag``, from the resets before it."""
        epoch = shift = 0
        for t, change in self._shifts:
            if t <= t_bag:
                epoch += 1
                shift += change
        return epoch, shift

    # -- clock jumps ---------------------------------------------------------------------------
    def _settle(self, st: _Topic, stamp: int) -> list:
        """The topic's message after a stamp far back: going on from it, the topic's clock jumped."""
        s_tbag, s_stamp, s_raw, s_item = st.suspect
        st.suspect = None
        if not s_stamp <= stamp <= s_stamp + self.jump:
            self._late(st, s_stamp, BACKWARDS)  # one wild stamp
            return []
        p = self._open
        if p is None:
            change = (s_stamp - s_tbag) - (st.last - st.last_tbag)
            p = self._open = _Jump(s_tbag, st.last, st.last - s_stamp, change)
            self._shifts.append((s_tbag, change))
        p.topics.append(st.topic)
        st.epoch += 1
        st.last = st.last_raw = None
        st.clear_window()
        out = self._take(st, st.epoch, s_stamp, s_tbag, s_raw, s_item)
        if not self._missing(p):
            self._close(p)
        return out

    def _alive(self, since: int) -> list[_Topic]:
        return [
            st
            for st in self._topics.values()
            if st.clock.source == "header" and st.seen_tbag is not None and st.seen_tbag >= since
        ]

    def _missing(self, p: _Jump) -> list[str]:
        return [st.topic for st in self._alive(p.t_bag - self.grace) if st.topic not in p.topics]

    def _close(self, p: _Jump) -> None:
        self._open = None
        others = tuple(self._missing(p))
        problem = ClockProblem(
            "partial" if others else "reset",
            p.before,
            self._at(p.before),
            tuple(p.topics),
            tuple(self._topics[t].clock.sensor for t in (p.topics if others else ())),
            back_s=(-p.change if abs(p.change) >= self.jump else p.back) * 1e-9,
            receive_ran_on=abs(p.change) >= self.jump,
            others=others,
        )
        self._problem(problem, refuse=bool(others) or not self.split)

    def _problem(self, problem: ClockProblem, refuse: bool) -> None:
        self.problems.append(problem)
        if refuse and not self.survey:
            raise MissionError(f"{self.path}: {problem.describe()}")

    # -- crowding and repeats ------------------------------------------------------------------
    def _note(self, st: _Topic, flags: int, t_bag: int, stamp: int) -> None:
        if (
            not st.note(flags, stamp)
            or st.flagged
            or self._interleaved
            or not (st.crowded >= CROWDED_MIN and st.clock.period_ns or st.repeats >= REPEATS_MIN)
        ):
            return
        st.flagged = True
        if st.repeats >= REPEATS_MIN:
            st.repeating = min(s for f, s in st.window if f >> 1)
        regular = [s for s in self._alive(t_bag - self.grace) if s.clock.period_ns]
        if len(regular) >= 2 and all(s.flagged for s in regular):
            first = min(s for x in regular for f, s in x.window if f)
            self._crowd_since = None
            for x in self._topics.values():
                x.clear_window()
            self._interleaved = True  # the stamps mean nothing from here on: nothing more to find in them
            sensors = tuple(x.clock.sensor for x in regular)
            self._problem(
                ClockProblem("interleaved", first, self._at(first), tuple(x.topic for x in regular), sensors),
                refuse=True,
            )
        elif self._crowd_since is None:
            self._crowd_since = t_bag

    def _expire(self, t_bag: int) -> None:
        if self._open is not None and t_bag > self._open.t_bag + self.grace:
            self._close(self._open)
        if self._crowd_since is not None and t_bag > self._crowd_since + self.grace:
            self._settle_crowding()

    def _settle_crowding(self) -> None:
        """Flagged topics that were not all of the regular ones: repeats are a clock problem of
        their own; crowding alone is a change of rate, nothing wrong."""
        self._crowd_since = None
        for st in self._topics.values():
            first = st.repeating
            st.clear_window()
            if first is not None and ("repeats", st.topic) not in self._reported:
                self._reported.add(("repeats", st.topic))
                self._problem(
                    ClockProblem("repeats", first, self._at(first), (st.topic,), (st.clock.sensor,)), refuse=True
                )
