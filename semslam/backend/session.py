"""The graph back-end's iSAM2 session: the factors of the window iSAM2 holds with their owners (every
factor of the mission too when the batch needs them), updates with recovery from a failed one, and the
batch re-optimisation and marginals at the end."""

from __future__ import annotations

import math
from collections.abc import Iterable

import gtsam
import numpy as np

from semslam.backend.marginal import joint_covariance, marginal_covariance
from semslam.backend.window import keyframe_keys, subset, value_of
from semslam.errors import solver_failure

# A factor with its owner: None for navigation, else the id of the landmark it observes.
Owned = tuple[gtsam.NonlinearFactor, int | None]


class IsamSession:
    """iSAM2 over the factors committed to it.

    ``window`` is the factors iSAM2 holds with their owners (those on variables still in the smoothing
    window, the marginals of what left it, and the priors of landmarks that came back), ``initial`` the
    first value of every variable in it (a fallback for recovery). With ``keep_all`` (the batch),
    ``factors`` is every factor of the mission; otherwise it stays empty, so that memory stays bounded
    once the window has filled (a 2-hour survey created 154k factors, ~3 KB each), and ``initial``
    forgets what left the window. ``n_committed`` counts the factors committed either way.

    A keyframe's navigation factors may be *deferred* (:meth:`defer`): they wait, with their new
    variables, for the next update (:meth:`commit`, :meth:`flush`), so that a scan's keyframe goes
    into iSAM2 with the scan's landmark factors in one update.
    iSAM2 checks for relinearisation every ``relinearize_skip`` updates *as if* each deferred
    keyframe had been its own update (``force_relinearize`` on the update that holds the one that
    would have checked), so the cadence in mission time is the one of committing them one by one."""

    def __init__(
        self, relinearize_threshold: float, relinearize_skip: int, diagnostics: list[str], keep_all: bool = True
    ):
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(relinearize_threshold)
        # iSAM2's own count never checks (its first update only: nothing to relinearise yet); the
        # session asks for the checks by its count of updates, deferred keyframes included.
        params.relinearizeSkip = 1 << 30
        # a slide removes the factors of what leaves (:meth:`slide_out`): new factors take their slots,
        # so that iSAM2's factor list stays the window's size on a survey of hours
        params.findUnusedFactorSlots = True
        self.relinearize_skip = relinearize_skip
        self.diagnostics = diagnostics
        self.keep_all = keep_all
        self.factors: list[Owned] = []
        self.window: list[Owned] = []
        self.window_factor_keys: list[tuple[int, ...]] = []  # each window factor's keys (read once: keys() copies)
        self._slots: list[int] = []  # each window factor's index in iSAM2
        self.owners: set[int] = set()  # every landmark a committed factor observes
        self.n_committed = 0
        self.initial = gtsam.Values()
        self.pending: list[Owned] = []  # deferred navigation factors (:meth:`defer`)
        self.pending_values = gtsam.Values()
        self.n_pending = 0  # the updates they would have been
        self._anchor: tuple[int, int] | None = None  # the newest keyframe's keys when they were deferred
        self._start(params)

    def _start(self, params: gtsam.ISAM2Params) -> None:
        """A fresh iSAM2, and a Python handle on its linearisation point, held for its lifetime.

        A CustomFactor's callback receives the Values it is linearised at through pybind11, which
        passes a C++ ``const Values&`` by copy unless that object already has a Python wrapper.
        iSAM2 linearises at its internal θ, so without the handle every callback of a line,
        displacement or biased-attitude factor copied the whole of θ (every keyframe, velocity
        and landmark): a cost that grew with the mission. ``getLinearizationPoint`` returns θ by
        reference (keeping iSAM2 alive), and pybind11 then hands that registered object to the
        callbacks."""
        self.isam = gtsam.ISAM2(params)
        self.theta = self.isam.getLinearizationPoint()
        self.n_updates = 0  # updates of this iSAM2, deferred keyframes counted one each
        self.relinearized = 0  # variables iSAM2 relinearised, summed over its updates

    def _update(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n: int = 1, last: tuple[int, ...] = ()
    ) -> list[int]:
        """iSAM2 ``update`` standing for ``n`` updates; relinearisation is checked if one of them
        would have checked (every ``relinearize_skip``-th). Returns iSAM2's indices of the new factors.
        ``last``: keys of the new factors to eliminate after the others (iSAM2 orders the new
        factors' keys last; these then form the root clique, whose marginal is cheap to read)."""
        first = self.n_updates + 1
        self.n_updates += n
        check = (self.n_updates // self.relinearize_skip) > ((first - 1) // self.relinearize_skip)
        groups = None
        observed = {k for i in range(graph.size()) for k in graph.at(i).keys()} if last else set()
        last = tuple(k for k in last if k in observed)
        if last and len(last) < len(observed):
            groups = gtsam.KeyGroupMap()
            for k in observed:
                groups.insert2(k, 2 if k in last else 1)
        result = self.isam.update(graph, values, constrainedKeys=groups, force_relinearize=check)
        self.relinearized += result.getVariablesRelinearized()
        return list(result.getNewFactorsIndices())

    def _hold(self, factors: list[Owned], slots: list[int]) -> None:
        """``factors`` join the window, at iSAM2's indices ``slots``."""
        self.window.extend(factors)
        self.window_factor_keys.extend(tuple(f.keys()) for f, _ in factors)
        self._slots.extend(slots)

    def _reset_window(self) -> None:
        self.window, self.window_factor_keys, self._slots = [], [], []

    # ------------------------------------------------------------------ estimates
    def value(self, key: int):
        return value_of(self.isam, key)

    def pose(self, key: int) -> gtsam.Pose3:
        return self.isam.calculateEstimatePose3(key)

    def vector(self, key: int) -> np.ndarray:
        return np.asarray(self.isam.calculateEstimateVector(key))

    def estimate(self) -> gtsam.Values:
        return self.isam.calculateEstimate()

    def root_marginal(self, key: int) -> np.ndarray:
        """The marginal covariance of a variable of the root clique (the newest keyframe), cheaply."""
        return marginal_covariance(self.isam, key)

    def root_joint(self, keys: list[int]) -> np.ndarray:
        """The joint marginal covariance of variables of the root clique (the newest keyframe's), cheaply."""
        return joint_covariance(self.isam, keys)

    def marginal(self, key: int) -> np.ndarray:
        return self.isam.marginalCovariance(key)

    # ------------------------------------------------------------------ updates
    def defer(self, factors: list[Owned], values: gtsam.Values, anchor: tuple[int, int]) -> None:
        """Navigation factors and their new variables for the next update (see the class)."""
        self.pending.extend(factors)
        self.pending_values.insert(values)
        self.n_pending += 1
        self._anchor = anchor

    def is_pending(self, key: int) -> bool:
        """``key`` is a deferred variable, not yet in iSAM2."""
        return self.pending_values.exists(key)

    def flush(self, stamp: int = 0) -> bool:
        """The deferred factors into iSAM2 now; False if there were none."""
        if not self.pending:
            return False
        self.commit([], gtsam.Values(), self._anchor, stamp=stamp)
        return True

    def commit(
        self,
        factors: list[Owned],
        values: gtsam.Values,
        anchor: tuple[int, int],
        priors: list[Owned] = (),
        stamp: int = 0,
    ) -> list[int] | None:
        """Add factors (with their owners) and new variables to iSAM2, and ``priors`` that only the
        window holds (a returning landmark's). On a failure, the landmark factors of this update are
        dropped and iSAM2 is rebuilt from the rest (:meth:`rebuild`, ``anchor``: the newest keyframe's
        pose and velocity keys). Deferred factors (:meth:`defer`) go in with them. Returns None when
        the update went through, else the owners dropped."""
        n = 1
        if self.pending:
            merged = gtsam.Values(self.pending_values)
            merged.insert(values)
            factors, values, n = [*self.pending, *factors], merged, self.n_pending + (len(factors) > 0)
            self.pending, self.pending_values, self.n_pending = [], gtsam.Values(), 0
        graph = gtsam.NonlinearFactorGraph()
        for f, _ in [*factors, *priors]:
            graph.add(f)
        # the newest keyframe's variables, the heading bias and its rate when modelled (keys no new factor
        # touches are dropped)
        last = keyframe_keys(gtsam.Symbol(anchor[0]).index())
        try:
            slots = self._update(graph, values, n, last=last)
        except RuntimeError as exc:
            msg = solver_failure(exc)
            owners = sorted({o for _, o in factors if o is not None})
            self.diagnostics.append(f"{stamp}: iSAM2 update failed ({msg}); dropped the factors of landmarks {owners}")
            self.rebuild([(f, o) for f, o in factors if o is None], values, anchor)
            return owners
        self._keep(factors)
        self.owners.update(o for _, o in factors if o is not None)
        self._hold([*factors, *priors], slots)  # the graph's order
        self.initial.insert_or_assign(values)  # a returning landmark's key is there already
        return None

    def _keep(self, factors: list[Owned]) -> None:
        self.n_committed += len(factors)
        if self.keep_all:
            self.factors.extend(factors)

    def owns(self, owner: int) -> bool:
        """Some committed factor observes landmark ``owner``."""
        return owner in self.owners

    def window_keys(self) -> set[int]:
        """Every variable a factor of the window holds."""
        return {k for keys in self.window_factor_keys for k in keys}

    def rebuild(self, navigation: list[Owned], values: gtsam.Values, anchor: tuple[int, int]) -> None:
        """A fresh iSAM2 from the window's factors plus ``navigation`` (this update's, the landmark
        factors left out), at the current estimate. Should that fail too, a weak prior on the pose and
        velocity keys ``anchor`` (the newest keyframe's) re-anchors the system."""
        try:
            estimate = self.isam.calculateEstimate()
        except RuntimeError:
            estimate = gtsam.Values(self.initial)
        self._keep(navigation)
        window = [*self.window, *navigation]
        self._reset_window()
        keep = {k for f, _ in window for k in f.keys()}
        full = gtsam.Values()
        for src in (estimate, values, self.initial):
            for key in src.keys():
                if key in keep and not full.exists(key):
                    full.insert(key, value_of(src, key))
        graph = gtsam.NonlinearFactorGraph()
        for f, _ in window:
            graph.add(f)
        params = self.isam.params()
        self._start(params)
        try:
            slots = self._update(graph, full)
        except RuntimeError as exc:
            x, v = anchor
            prior = gtsam.PriorFactorPose3(x, full.atPose3(x), gtsam.noiseModel.Isotropic.Sigma(6, 10.0))
            vprior = gtsam.PriorFactorVector(v, value_of(full, v), gtsam.noiseModel.Isotropic.Sigma(3, 10.0))
            self._keep([(prior, None), (vprior, None)])
            window += [(prior, None), (vprior, None)]
            graph.add(prior)
            graph.add(vprior)
            self._start(params)
            slots = self._update(graph, full)
            self.diagnostics.append(
                f"rebuild needed a weak re-anchoring prior on {gtsam.Symbol(x).string()} ({solver_failure(exc)})"
            )
        self._hold(window, slots)
        self.initial = full

    def restart(self, window: list[Owned], values: gtsam.Values) -> None:
        """iSAM2 afresh on ``window`` (the smoothing window after a slide) at ``values``; on a failure
        the session is left as it was and the RuntimeError raised."""
        old = self.isam, self.theta, self.n_updates
        graph = gtsam.NonlinearFactorGraph()
        for f, _ in window:
            graph.add(f)
        try:
            self._start(self.isam.params())
            slots = self._update(graph, values)
        except RuntimeError:
            self.isam, self.theta, self.n_updates = old
            raise
        self._reset_window()
        self._hold(window, slots)
        if not self.keep_all:
            self.initial = gtsam.Values(values)

    def slide_out(self, leaving: list[int], marginal: list[Owned], values: gtsam.Values) -> None:
        """What leaves the window, without a restart: the window's factors at positions ``leaving``
        are removed from iSAM2 and the ``marginal`` of what they carried on the rest added, in one
        update. iSAM2 drops the variables left without a factor (the keyframes and landmarks that
        leave); it relinearises nothing and re-eliminates the cliques the removed factors touched.
        The kept factors stay linearised where iSAM2 had them (a restart relinearised the whole
        window at the estimate: a batch linearisation and elimination, and a fill-reducing order of
        the whole window in place of iSAM2's incremental one). With the marginal linearised at
        iSAM2's linearisation point, the kept variables' estimate and covariance would stay exactly
        those of before (on the linear system); at the estimate they move by second-order terms.
        ``values``: the estimate (that of the kept variables is the fallback of a later rebuild).
        The update counts as the first of a fresh iSAM2 (the relinearisation cadence of a restart).
        On a failure iSAM2 may be left broken: the caller
        restarts it (:meth:`restart`); the RuntimeError is raised."""
        gone = set(leaving)
        remove = [self._slots[i] for i in leaving]
        graph = gtsam.NonlinearFactorGraph()
        for f, _ in marginal:
            graph.add(f)
        slots = list(self.isam.update(graph, gtsam.Values(), remove).getNewFactorsIndices())
        self.n_updates = 1
        kept = [i for i in range(len(self.window)) if i not in gone]
        window, keys, old = self.window, self.window_factor_keys, self._slots
        self.window = [window[i] for i in kept]
        self.window_factor_keys = [keys[i] for i in kept]
        self._slots = [old[i] for i in kept]
        self._hold(marginal, slots)
        if not self.keep_all:
            self.initial = subset(values, self.window_keys())

    # ------------------------------------------------------------------ the whole mission
    def graph(self) -> gtsam.NonlinearFactorGraph:
        """Every factor of the mission (``keep_all``), else the window's."""
        graph = gtsam.NonlinearFactorGraph()
        for f, _ in self.factors if self.keep_all else self.window:
            graph.add(f)
        return graph

    def batch(self, initial: gtsam.Values, max_iterations: int) -> gtsam.Values:
        """Levenberg–Marquardt over the whole mission from ``initial`` (raises RuntimeError on failure)."""
        if not self.keep_all:
            raise ValueError("the batch needs every factor of the mission: IsamSession(keep_all=True)")
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations)
        return levenberg_marquardt(self.graph(), initial, params)

    def marginals(self, values: gtsam.Values):
        """Marginals of ``values`` from one batch factorisation of :meth:`graph` (iSAM2's
        per-variable marginals cost a partial re-elimination each: minutes for a mission's
        keyframes); None (iSAM2's, one by one) if the batch system is indeterminate. Without
        ``keep_all`` they cover the window's variables only (with the marginal of what left it)."""
        graph = self.graph()
        if not self.keep_all:  # only the window's variables: a Values with more is refused
            values = subset(values, self.window_keys())
        try:
            return gtsam.Marginals(graph, values)
        except RuntimeError as exc:
            self.diagnostics.append(f"batch marginals failed ({str(exc).splitlines()[0]}); iSAM2 marginals used")
            return None

    def joint_blocks(
        self, marginals, keys: Iterable[int], chunk: int = 60, known: dict[int, np.ndarray] | None = None
    ) -> dict[int, np.ndarray]:
        """Marginal covariances of ``keys``: those in ``known`` as given (what left the window, at the
        time it left), the others from joint marginals over chunks of them (``marginals``: a
        ``gtsam.Marginals``, or the iSAM2 itself; in a graph where every landmark links to every pose,
        one joint marginal of 60 variables costs about as much as one or two single ones), else
        iSAM2's one by one. A key that fails is left out."""
        known = known or {}
        out: dict[int, np.ndarray] = {k: known[k] for k in keys if k in known}
        keys = [k for k in keys if k not in out]
        if marginals is not None:
            for a in range(0, len(keys), chunk):
                part = keys[a : a + chunk]
                try:
                    J = marginals.jointMarginalCovariance(gtsam.KeyVector(part))
                    out.update({k: np.asarray(J.at(k, k)) for k in part})
                except (RuntimeError, IndexError):  # indeterminate, or not in the graph: key by key
                    pass
        for k in keys:
            if k not in out:
                try:
                    out[k] = self.isam.marginalCovariance(k)
                except (RuntimeError, IndexError):  # indeterminate, or left the window
                    pass
        return out


def levenberg_marquardt(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, params) -> gtsam.Values:
    """GTSAM's Levenberg–Marquardt, iterated here exactly as ``optimize()`` does (its
    ``defaultOptimize`` loop and stopping rules), holding a Python handle on the optimiser's current
    values during each iteration: the iteration linearises at them, and its CustomFactor callbacks
    then get that object instead of a copy of every variable (see :meth:`IsamSession._start`).
    The error evaluations of trial steps still copy."""
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    new = opt.error()
    if new <= params.getErrorTol() or opt.iterations() >= params.getMaxIterations():
        return gtsam.Values(opt.values())
    while True:
        current = new
        held = opt.values()  # alive while iterate() linearises at it
        opt.iterate()
        del held  # an accepted step replaced the values it pointed to
        new = opt.error()
        if not (
            opt.iterations() < params.getMaxIterations()
            and not gtsam.checkConvergence(params, current, new)
            and math.isfinite(current)
        ):
            return gtsam.Values(opt.values())
