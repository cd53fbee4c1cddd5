"""Marginalisation for the graph back-end's bounded smoothing window.

A full smoother's cost per update grows on long missions: on a lawnmower coverage the graph is a
2-D grid, and iSAM2's separators grow with the width covered. The online smoother therefore keeps a
window of recent keyframes and the landmarks they see; what leaves the window (old keyframes, and
landmarks no kept keyframe observes) is marginalised, its information kept as a linear factor on
the variables it was connected to (the separator), linearised at the current estimate. This is
the factor BatchFixedLagSmoother computes (GTSAM's ``CalculateMarginalFactors``); GTSAM's incremental
fixed-lag smoother is not used because its in-tree marginalisation of iSAM2 leaves has open
failures on Bayes trees like ours (borglab/gtsam #1638, #1680). Instead the factors of what leaves
are removed from iSAM2 with the marginal added in the same update, and iSAM2 drops the variables
left without a factor.
"""

from __future__ import annotations

import bisect
import time
from collections.abc import Iterable, Mapping

import gtsam
import numpy as np

from semslam.errors import solver_failure
from semslam.estimation import SpillLog

LANDMARK_CHARS = frozenset(map(ord, "lps"))  # object points, pipe lines, structures
POSE_CHARS = frozenset(map(ord, "xs"))  # Pose3-valued keys (keyframes, structures)
POINT_CHARS = frozenset(map(ord, "l"))  # Point3-valued keys


def value_of(src: gtsam.Values | gtsam.ISAM2, key: int):
    """A variable of ``src`` (Values, or iSAM2's current estimate) by its symbol character: a Pose3,
    or a numpy vector (point, line, velocity, bias)."""
    c = gtsam.Symbol(key).chr()
    if isinstance(src, gtsam.Values):
        if c in POSE_CHARS:
            return src.atPose3(key)
        return src.atPoint3(key) if c in POINT_CHARS else src.atVector(key)
    if c in POSE_CHARS:
        return src.calculateEstimatePose3(key)
    return src.calculateEstimatePoint3(key) if c in POINT_CHARS else src.calculateEstimateVector(key)


def subset(values: gtsam.Values, keys: Iterable[int]) -> gtsam.Values:
    out = gtsam.Values()
    for k in keys:
        out.insert(k, value_of(values, k))
    return out


def split_factors(
    factors: list[tuple], drop: set[int], factor_keys: list | None = None
) -> tuple[list[tuple], list[tuple], set[int]]:
    """(kept, leaving, the kept ones' keys): the factors touching no dropped key, and the others
    (``factor_keys``: each factor's keys, when already read: each ``keys()`` call copies them)."""
    if factor_keys is None:
        factor_keys = [item[0].keys() for item in factors]
    kept, leaving, kept_keys = [], [], set()
    for item, keys in zip(factors, factor_keys):
        if not drop.isdisjoint(keys):
            leaving.append(item)
        else:
            kept.append(item)
            kept_keys.update(keys)
    return kept, leaving, kept_keys


def marginal_factors(
    leaving: list[tuple], values: gtsam.Values, drop: set[int], leaving_keys: list | None = None
) -> list[gtsam.LinearContainerFactor]:
    """The information the ``leaving`` factors carry on their non-dropped variables, with the
    dropped ones eliminated: linear factors at ``values`` (which must hold every variable the
    factors touch). ``leaving_keys``: each factor's keys, when already read (``keys()`` copies).
    Raises RuntimeError if the dropped variables are not determined."""
    graph = gtsam.NonlinearFactorGraph()
    for f, *_ in leaving:
        graph.add(f)
    linear = graph.linearize(values)
    if leaving_keys is None:
        leaving_keys = [f.keys() for f, *_ in leaving]
    present = sorted({k for keys in leaving_keys for k in keys if k in drop})
    _, remaining = linear.eliminatePartialMultifrontal(gtsam.KeyVector(present))  # COLAMD order
    out = []
    for i in range(remaining.size()):
        g = remaining.at(i)
        if g is None or len(g.keys()) == 0:
            continue
        out.append(gtsam.LinearContainerFactor(g, subset(values, g.keys())))
    return out


# Keyframes that leave the window keep their covariance one in this many (each costs iSAM2 a marginal;
# the result samples result_covariance_keyframes of a mission's keyframes, fewer on long missions).
LEFT_COVARIANCE_EVERY = 10


class LeftCovariances(Mapping):
    """Key -> the marginal covariance it had when it left the window (the last given, as a dict's
    ``update`` keeps it), on disk as they come (:class:`SpillLog`: a survey of hours leaves thousands);
    read back, once, when the result asks (in the column-major order GTSAM gives them)."""

    DIM = 6  # the largest variable: a pose (keyframes, structures)

    def __init__(self):
        self._rows = SpillLog([("key", "<u8"), ("dim", "<i8"), ("cov", "<f8", (self.DIM, self.DIM))], chunk=256)
        self._read: dict[int, np.ndarray] | None = {}

    def update(self, covariances: Mapping[int, np.ndarray]) -> None:
        for key, cov in covariances.items():
            d = len(cov)
            padded = np.zeros((self.DIM, self.DIM))
            padded[:d, :d] = cov
            self._rows.append(key, d, padded)
        if covariances:
            self._read = None

    def _all(self) -> dict[int, np.ndarray]:
        if self._read is None:
            rows = self._rows.array()
            self._read = {
                int(k): np.asfortranarray(c[:d, :d]) for k, d, c in zip(rows["key"], rows["dim"], rows["cov"])
            }
        return self._read

    def __getitem__(self, key: int) -> np.ndarray:
        return self._all()[key]

    def __iter__(self):
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())


# Keyframe variable keys: pose, body velocity, AHRS heading bias, the bias's drift rate, and the gyro's bias.
X = gtsam.symbol_shorthand.X
V = gtsam.symbol_shorthand.V
B = gtsam.symbol_shorthand.B
D = gtsam.symbol_shorthand.D
G = gtsam.symbol_shorthand.G


# a keyframe's pose, velocity, heading bias, its rate, the gyro's bias
KEYFRAME_CHARS = (ord("x"), ord("v"), ord("b"), ord("d"), ord("g"))


def keyframe_keys(i: int) -> tuple[int, ...]:
    """Every variable keyframe i may have (X, V, B, D, G): the ones a mission does not model are in no factor."""
    return X(i), V(i), B(i), D(i), G(i)


FROZEN_ROW = np.dtype(
    [("R", "f8", (3, 3)), ("t", "f8", 3), ("v", "f8", 3), ("b", "f8"), ("d", "f8"), ("g", "f8", 3), ("has", "?", 5)]
)


class FrozenValues:
    """The estimates of what left the window, read at random (a keyframe's pose for an older
    observation) and all at the end: each keyframe's pose, velocity and heading bias in one
    :data:`FROZEN_ROW` by its index (165 bytes a keyframe, where GTSAM ``Values`` take ~450), the
    landmarks' in a ``gtsam.Values`` (a landmark may come back and leave again). A pose comes back as
    the same ``Pose3`` (``Rot3`` holds its matrix)."""

    __slots__ = ("landmarks", "_rows")

    def __init__(self):
        self.landmarks = gtsam.Values()
        self._rows = np.zeros(0, FROZEN_ROW)

    def insert_or_assign(self, values: gtsam.Values, keys: Iterable[int]) -> None:
        """The estimates in ``values`` of ``keys`` (those it holds)."""
        for key in keys:
            if not values.exists(key):
                continue
            symbol = gtsam.Symbol(key)
            c = symbol.chr()
            if c not in KEYFRAME_CHARS:
                self.landmarks.insert_or_assign(key, value_of(values, key))
                continue
            row = self._row(symbol.index())
            if c == KEYFRAME_CHARS[0]:
                pose = values.atPose3(key)
                row["R"], row["t"] = pose.rotation().matrix(), pose.translation()
            elif c == KEYFRAME_CHARS[1]:
                row["v"] = values.atVector(key)
            elif c == KEYFRAME_CHARS[4]:
                row["g"] = values.atVector(key)
            else:  # the heading bias or its rate
                row[chr(c)] = values.atVector(key)[0]
            row["has"][KEYFRAME_CHARS.index(c)] = True

    def _row(self, k: int) -> np.ndarray:
        if k >= len(self._rows):
            grown = np.zeros(max(k + 1, 2 * len(self._rows), 64), FROZEN_ROW)
            grown[: len(self._rows)] = self._rows
            self._rows = grown
        return self._rows[k : k + 1][0]

    def atPose3(self, key: int) -> gtsam.Pose3:  # noqa: N802 (gtsam.Values' name)
        k = gtsam.Symbol(key).index()
        if k >= len(self._rows) or not self._rows["has"][k, 0]:
            raise IndexError(f"no frozen pose of keyframe {k}")
        row = self._rows[k]
        return gtsam.Pose3(gtsam.Rot3(row["R"]), row["t"])

    def insert_into(self, values: gtsam.Values) -> None:
        """Every frozen estimate that ``values`` does not hold (not a landmark that came back)."""
        for key in self.landmarks.keys():
            if not values.exists(key):
                values.insert(key, value_of(self.landmarks, key))
        for k in np.flatnonzero(self._rows["has"].any(axis=1)):
            row = self._rows[k]
            has = row["has"]
            for j, c in enumerate(KEYFRAME_CHARS):
                key = gtsam.Symbol(chr(c), int(k)).key()
                if not has[j] or values.exists(key):
                    continue
                if j == 0:
                    values.insert(key, gtsam.Pose3(gtsam.Rot3(row["R"]), row["t"]))
                elif j in (1, 4):
                    values.insert(key, np.array(row["v" if j == 1 else "g"]))
                else:
                    values.insert(key, np.array([row[chr(c)]]))


class SlidingWindow:
    """The online smoother's window of ``window_s`` seconds: the oldest keyframe in it, and the frozen
    estimates of everything that left it; with ``keep_covariances``, also the marginal covariances
    (of poses, velocities and landmarks) it had when it left, for a result made without the factors
    of the whole mission."""

    def __init__(self, window_s: float | None, diagnostics: list[str], keep_covariances: bool = False):
        self.window_s = window_s
        self.diagnostics = diagnostics
        self.keep_covariances = keep_covariances
        self.first_active = 0  # the oldest keyframe in the window
        self.frozen = FrozenValues()  # the estimates of what left it
        self.left_covariance = LeftCovariances()  # key -> marginal covariance when it left
        self.slides: list[dict] = []  # one row per marginalisation, for benchmarks
        self.returns = 0  # marginalised landmarks seen again
        self._slide_after = 0  # stamp before which no slide is tried (after a failed one)

    def slide(self, session, kf_stamps: list[int]) -> tuple[set[int], gtsam.Values] | None:
        """Once the window spans 1.5 × ``window_s``, marginalise the keyframes older than
        ``window_s`` and the landmarks no kept keyframe observes: their factors leave iSAM2 and their
        marginal on the rest, linearised at the current estimate, comes in, in one iSAM2 update
        (:meth:`IsamSession.slide_out`: what it re-eliminates, no relinearisation; until stop 38 iSAM2
        was restarted on the window, a batch linearisation and elimination, ~2× the cost). Returns the
        keys that left and the estimate they left with (None: no slide)."""
        w = self.window_s
        now = kf_stamps[-1]
        if w is None or now < self._slide_after or (now - kf_stamps[self.first_active]) * 1e-9 < 1.5 * w:
            return None
        session.flush(now)  # deferred keyframes (see IsamSession.defer) into iSAM2 first
        t0, c0 = time.perf_counter(), time.process_time()
        b = min(bisect.bisect_left(kf_stamps, now - int(w * 1e9)), len(kf_stamps) - 1)
        kept_kf = {key for i in range(b, len(kf_stamps)) for key in keyframe_keys(i)}
        live, landmark_keys = set(), set()
        factor_keys = session.window_factor_keys
        for keys in factor_keys:
            lms = [k for k in keys if k >> 56 in LANDMARK_CHARS]  # a Symbol's character is the key's top byte
            landmark_keys.update(lms)
            if lms and any(k in kept_kf for k in keys):
                live.update(lms)
        drop = {key for i in range(self.first_active, b) for key in keyframe_keys(i)} | (landmark_keys - live)
        t1 = time.perf_counter()
        estimate = session.estimate()
        covariances = self._covariances(session, drop, b) if self.keep_covariances else {}
        t_cov = time.perf_counter() - t1
        out = [i for i, keys in enumerate(factor_keys) if not drop.isdisjoint(keys)]  # the factors that leave
        try:
            # at the estimate, which the marginal keeps for good (at iSAM2's older linearisation point the
            # 0.5 h survey of bench_graph ended 7 % worse: ATE 0.175 against 0.168 m)
            leaving, leaving_keys = [session.window[i] for i in out], [factor_keys[i] for i in out]
            marginal = [(m, None) for m in marginal_factors(leaving, estimate, drop, leaving_keys)]
            try:
                session.slide_out(out, marginal, estimate)
            except RuntimeError as exc:  # iSAM2 afresh on the window, as the slides did before
                self.diagnostics.append(f"{now}: removing what left failed ({solver_failure(exc)}); iSAM2 restarted")
                kept, _, kept_keys = split_factors(session.window, drop, factor_keys)
                session.restart(kept + marginal, subset(estimate, kept_keys.union(*(m.keys() for m, _ in marginal))))
            window = session.window
        except RuntimeError as exc:
            self._slide_after = now + int(0.5 * w * 1e9)
            self.diagnostics.append(
                f"{now}: marginalising keyframes before {b} failed ({solver_failure(exc)}); retried in {0.5 * w:g} s"
            )
            return None
        self.first_active = b
        self.slides.append(
            {
                "stamp": now,
                "first_keyframe": b,
                "left_landmarks": len(drop & landmark_keys),
                "separator": len({k for m, _ in marginal for k in m.keys()}),
                "window_factors": len(window),
                "seconds": time.perf_counter() - t0,
                "cpu_seconds": time.process_time() - c0,  # of the process (wall time says little under load)
                "covariance_seconds": t_cov,
            }
        )
        self.frozen.insert_or_assign(estimate, drop)
        self.left_covariance.update(covariances)
        return drop, estimate

    def _covariances(self, session, drop: set[int], b: int, chunk: int = 60) -> dict[int, np.ndarray]:
        """iSAM2's marginal covariances of the landmarks about to leave and of every
        ``LEFT_COVARIANCE_EVERY``-th keyframe's pose and velocity (before the slide takes them out of
        iSAM2, while it still holds them): the diagonal blocks of joint marginals over chunks of them
        (:meth:`IsamSession.joint_blocks`: each single marginal walks the Bayes tree again). A key
        iSAM2 cannot give is left out (its covariance is unknown: NaN)."""
        first = -(-self.first_active // LEFT_COVARIANCE_EVERY) * LEFT_COVARIANCE_EVERY
        keys = [k for i in range(first, b, LEFT_COVARIANCE_EVERY) for k in (X(i), V(i))]
        keys += sorted(k for k in drop if gtsam.Symbol(k).chr() in LANDMARK_CHARS)
        return session.joint_blocks(session.isam, keys, chunk)

    def estimate(self, session) -> gtsam.Values:
        """The window's estimate with the frozen estimates of everything that left it."""
        values = session.estimate()
        self.frozen.insert_into(values)
        return values
