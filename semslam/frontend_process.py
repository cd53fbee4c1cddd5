"""Front-ends that do not read the estimate, run in a process of their own.

A front-end that declares ``uses_view = False`` (it never reads the ``EstimateView``: the laser
takes "up" from the AHRS, the oracle reads ground truth) depends on nothing but the measurements,
so it can work a few scans ahead while the estimators work through the measurements before them.

The front-ends are pickled into worker processes and fed every measurement they consume, in order; they keep their state
there. Results come back in the same order: the observations of each front-end and the time it
took. Payloads are pickled in the worker, so that an object that cannot cross (or any exception)
is reported to the caller instead of hanging a queue's feeder thread.

Replicas: a front-end whose result for some measurement types depends only on that measurement and
on what it kept from its other types (``parallel_consumes``: the laser's scans, given the latest
AHRS reading) can run in several workers at once. Each worker holds a replica of every front-end;
a measurement that every front-end consuming it takes in parallel goes to one worker in turn, any
other measurement to all of them (so that each replica keeps the same state). A replicated
front-end observes only on its parallel types: its other types feed its state, nobody answers for
them, and the estimators go on without waiting (the laser's 9800 AHRS readings). Such state-only
measurements travel in batches, pickled once for all the workers, ahead of the next measurement
that is answered (one queue item per worker instead of one per reading and worker). A replica's ``finish()`` must not depend on the parallel
measurements (the first one's is used).
On 2 cores the laser's scans then take what CPU the estimators leave on both cores.

Start: a fork of this process would inherit its OpenMP and GTSAM threads, so the workers are forked
from multiprocessing's fork server instead, a fresh interpreter (no threads) that has imported the
front-ends' modules once (``set_forkserver_preload``): a spawned worker would import them itself
(open3d and all) before its first message, a forked one starts at once after the server's import,
once per process. The server lives until this process exits, with the
environment it started with: each worker is handed this process's environment as it is when the
worker is created (a front-end may read it at use, e.g. the recogniser's cache folder).

What each of these saves on the tank mission: experiments/estimators/README.md.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import queue
import threading
import time
import traceback
from collections import deque
from collections.abc import Sequence

from semslam.mission.measurements import Measurement
from semslam.registry import Frontend

_FINISH = "finish"
WORKER_NICE = 10
_STATE_BATCH = 256  # state-only measurements sent at the latest after this many


def runs_in_process(frontend) -> bool:
    """A :class:`~semslam.registry.Frontend` that never reads the estimate (``uses_view = False``)."""
    return isinstance(frontend, Frontend) and not frontend.uses_view


def default_workers() -> int:
    """One worker per core, at most 4 (the estimators keep the main process busy too)."""
    return max(1, min(os.cpu_count() or 1, 4))


START_METHOD = "forkserver"


def _context(frontends: Sequence):
    """The workers' start method: forked from a server that has imported the front-ends' modules
    once (never a fork of this process, whose OpenMP and GTSAM threads a fork would inherit)."""
    if START_METHOD != "forkserver":
        return mp.get_context(START_METHOD)
    ctx = mp.get_context("forkserver")
    modules = {__name__, "threadpoolctl"} | {type(fe).__module__ for fe in frontends}
    modules.discard("__main__")
    ctx.set_forkserver_preload(sorted(modules))
    return ctx


class FrontendProcess:
    """Worker processes running ``frontends`` on the measurements submitted to them; results in
    submission order. ``workers`` > 1 only helps front-ends that declare ``parallel_consumes``."""

    def __init__(self, frontends: Sequence[Frontend], workers: int = 1):
        ctx = _context(frontends)
        self.names = [fe.name for fe in frontends]
        self._types = [tuple(fe.consumes) for fe in frontends]
        self._parallel = [tuple(fe.parallel_consumes) for fe in frontends]
        if not any(self._parallel):
            workers = 1  # replicas would all do the same work
        self._workers = [_Worker(ctx, list(frontends), i) for i in range(max(1, workers))]
        self._owners: deque[int] = deque()  # which worker answers each submitted measurement
        self._turn = 0
        self._state: list[Measurement] = []  # state-only measurements not yet sent

    def consumes(self, m: Measurement) -> bool:
        return any(isinstance(m, t) for t in self._types)

    def _observed(self, m: Measurement) -> bool:
        """Some front-end may observe on ``m``: one without parallel types, or one that takes ``m``'s
        type in parallel. A replicated front-end's other types only feed its state (no reply)."""
        return any(
            isinstance(m, types) and (not par or isinstance(m, par)) for types, par in zip(self._types, self._parallel)
        )

    def _shared(self, m: Measurement) -> bool:
        """Every front-end that consumes ``m`` takes it in parallel: one replica suffices."""
        return all(isinstance(m, par) for types, par in zip(self._types, self._parallel) if isinstance(m, types))

    def submit(self, m: Measurement) -> bool:
        """Send ``m`` to the workers; True if a result will come back for it (see :meth:`result`)."""
        if not self._observed(m):  # state only, for every replica
            self._state.append(m)
            if len(self._state) >= _STATE_BATCH:
                self._send_state()
            return False
        self._send_state()
        if len(self._workers) > 1 and self._shared(m):
            owner = self._turn
            self._turn = (self._turn + 1) % len(self._workers)
            self._workers[owner].send(m, reply=True)
        else:
            owner = 0
            for w in self._workers:
                w.send(m, reply=w.index == owner)
        self._owners.append(owner)
        return True

    def _send_state(self) -> None:
        """The pending state-only measurements to every worker, in one batch pickled once."""
        if self._state:
            batch = pickle.dumps(self._state, pickle.HIGHEST_PROTOCOL)
            self._state = []
            for w in self._workers:
                w.send(batch, reply=False)

    def result(self) -> dict[str, tuple[list, float]]:
        """The results of the next submitted measurement that has some: front-end name →
        (observations, seconds), for the front-ends that consume it."""
        return self._workers[self._owners.popleft()].receive(self.names)

    def finish(self) -> dict[str, tuple[object, float]]:
        """Every front-end's ``finish()`` summary (None without one) and its time (the first replica's)."""
        self._send_state()
        self._workers[0].send(_FINISH, reply=True)
        return self._workers[0].receive(self.names)

    def close(self) -> None:
        for w in self._workers:  # all told first: their exits overlap (~0.5 s each, open3d and all)
            w.stop()
        for w in self._workers:
            w.close()


class _Worker:
    def __init__(self, ctx, frontends: list, index: int):
        self.index = index
        self._in = ctx.Queue()
        self._out = ctx.Queue()
        self._proc = ctx.Process(
            target=_work,
            args=(frontends, self._in, self._out, dict(os.environ)),
            daemon=True,
            name=f"semslam-frontends-{index}",
        )
        # Started aside: a forkserver's start waits for its child's pid, i.e. for the server to have
        # imported the front-ends (~2 s, once per process), while the caller could be reading the
        # mission. Measurements sent meanwhile wait in the queue.
        self._start_error: BaseException | None = None
        self._starter: threading.Thread | None = threading.Thread(
            target=self._start, daemon=True, name=f"semslam-frontends-start-{index}"
        )
        self._starter.start()

    def _start(self) -> None:
        try:
            self._proc.start()
        except BaseException as exc:  # raised in the caller's thread by _started()
            self._start_error = exc

    def _started(self) -> None:
        """Wait for the process to have started; raise what starting it raised."""
        if self._starter is not None:
            self._starter.join()
            self._starter = None
        if self._start_error is not None:
            raise self._start_error

    def send(self, item, reply: bool) -> None:
        self._in.put((item, reply))

    def receive(self, names: list[str]):
        self._started()
        while True:
            try:
                kind, payload = pickle.loads(self._out.get(timeout=5.0))
                break
            except queue.Empty:  # the worker may have died without a word
                if not self._proc.is_alive():
                    raise RuntimeError(
                        f"the front-end process ({', '.join(names)}) died "
                        f"(exit code {self._proc.exitcode}; a script that runs the "
                        "pipeline must start it under `if __name__ == '__main__':`, "
                        "as the process imports the script)"
                    ) from None
        if kind == "error":
            exc, tb = payload
            exc.__notes__ = [*getattr(exc, "__notes__", []), f"in the front-end process:\n{tb}"]
            raise exc
        return payload

    def stop(self) -> None:
        if self._starter is not None:
            self._starter.join()  # a start that failed was raised by receive(), if anyone asked
        if self._proc.is_alive():
            self._in.put(None)

    def close(self) -> None:
        if self._starter is not None:
            self._starter.join()
        if self._proc.is_alive():
            self._proc.join(timeout=10)
            if self._proc.is_alive():
                self._proc.terminate()
        if not self._proc.is_alive():
            # Measurements still queued for a dead worker can never be read: without this, the
            # queue's feeder thread blocks on the full pipe and the interpreter hangs at exit.
            self._in.cancel_join_thread()
        self._in.close()
        self._out.close()


def _work(frontends: list, inq, outq, environ: dict[str, str]) -> None:
    from threadpoolctl import threadpool_limits

    # The caller's environment now, not the fork server's (frozen when the server started).
    os.environ.clear()
    os.environ.update(environ)

    # Below the estimators' priority: they consume the results in order, so on a machine with
    # fewer cores than processes a worker should take the CPU they leave, not the reverse.
    os.nice(WORKER_NICE)

    unreported: dict[str, float] = {}  # time spent on measurements without a reply, told with the next
    with threadpool_limits(limits=1, user_api="blas"):  # as in the pipeline: small matrices
        while True:
            msg = inq.get()
            if msg is None:
                return
            item, reply = msg
            try:
                if isinstance(item, bytes):  # a batch of state-only measurements (no reply)
                    for m in pickle.loads(item):
                        for name, (_, dt) in _process(frontends, m).items():
                            unreported[name] = unreported.get(name, 0.0) + dt
                    continue
                out = _process(frontends, item)
                if not reply:  # a replica keeping its state: another worker answers, if anyone
                    for name, (_, dt) in out.items():
                        unreported[name] = unreported.get(name, 0.0) + dt
                    continue
                out = {name: (o, dt + unreported.pop(name, 0.0)) for name, (o, dt) in out.items()}
                payload = pickle.dumps(("ok", out))
            except BaseException as exc:  # reported to the caller, which raises it
                try:
                    payload = pickle.dumps(("error", (exc, traceback.format_exc())))
                except Exception:
                    payload = pickle.dumps(("error", (RuntimeError(repr(exc)), traceback.format_exc())))
            outq.put(payload)


def _process(frontends: list, item) -> dict[str, tuple[object, float]]:
    """Front-end name → (result, seconds) of one measurement (observations), or of _FINISH (summary)."""
    out = {}
    if isinstance(item, str) and item == _FINISH:
        for fe in frontends:
            t0 = time.perf_counter()
            summary = fe.finish(None)
            out[fe.name] = (summary, time.perf_counter() - t0)
        return out
    for fe in frontends:
        if isinstance(item, tuple(fe.consumes)):
            t0 = time.perf_counter()
            obs = fe.process(item, None)
            out[fe.name] = (obs, time.perf_counter() - t0)
            par = tuple(fe.parallel_consumes)
            if obs and par and not isinstance(item, par):
                raise RuntimeError(
                    f"front-end {fe.name!r} observed on a {type(item).__name__}, which it "
                    "does not take in parallel: with parallel_consumes, its other "
                    "measurement types may only feed its state"
                )
    return out
