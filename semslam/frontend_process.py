"""Front-ends that do not read the estimate, run in a process of their own.

A front-end that declares ``uses_view = False`` (it never reads the ``EstimateView``: the laser
takes "up" from the AHRS, the oracle reads ground truth) depends on nothing but the measurements,
so it can work a few scans ahead while the estimators work through the measurements before them.
On the tank mission that is the laser's ~50 s beside the estimators' ~35 s on two cores.

The front-ends are pickled into one worker process (spawned: a fork would inherit the parent's
OpenMP and GTSAM threads) and fed every measurement they consume, in order; they keep their state
there. Results come back in the same order: the observations of each front-end and the time it
took. Payloads are pickled in the worker, so that an object that cannot cross (or any exception)
is reported to the caller instead of hanging a queue's feeder thread.
"""

from __future__ import annotations

import multiprocessing as mp
import pickle
import queue
import time
import traceback
from collections.abc import Sequence

from semslam.mission.measurements import Measurement

_FINISH = "finish"


def runs_in_process(frontend) -> bool:
    """A front-end that never reads the estimate (``uses_view = False``)."""
    return getattr(frontend, "uses_view", True) is False


class FrontendProcess:
    """One worker process running ``frontends`` on the measurements submitted to it, in order."""

    def __init__(self, frontends: Sequence):
        ctx = mp.get_context("spawn")
        self.names = [fe.name for fe in frontends]
        self._types = [tuple(fe.consumes) for fe in frontends]
        self._in = ctx.Queue()
        self._out = ctx.Queue()
        self._proc = ctx.Process(target=_work, args=(list(frontends), self._in, self._out), daemon=True,
                                 name="semslam-frontends")
        self._proc.start()
        self.in_flight = 0

    def consumes(self, m: Measurement) -> bool:
        return any(isinstance(m, t) for t in self._types)

    def submit(self, m: Measurement) -> None:
        self._in.put(m)
        self.in_flight += 1

    def result(self) -> dict[str, tuple[list, float]]:
        """The next submitted measurement's results: front-end name → (observations, seconds),
        for the front-ends that consume it."""
        self.in_flight -= 1
        return self._receive()

    def finish(self) -> dict[str, tuple[object, float]]:
        """Every front-end's ``finish()`` summary (None without one) and its time."""
        self._in.put(_FINISH)
        return self._receive()

    def close(self) -> None:
        if self._proc.is_alive():
            self._in.put(None)
            self._proc.join(timeout=10)
            if self._proc.is_alive():
                self._proc.terminate()
        if not self._proc.is_alive():
            # Measurements still queued for a dead worker can never be read: without this, the
            # queue's feeder thread blocks on the full pipe and the interpreter hangs at exit.
            self._in.cancel_join_thread()
        self._in.close()
        self._out.close()

    def _receive(self):
        while True:
            try:
                kind, payload = pickle.loads(self._out.get(timeout=5.0))
                break
            except queue.Empty:  # the worker may have died without a word
                if not self._proc.is_alive():
                    raise RuntimeError(f"the front-end process ({', '.join(self.names)}) died "
                                       f"(exit code {self._proc.exitcode}; a script that runs the "
                                       "pipeline must start it under `if __name__ == '__main__':`, "
                                       "as the process is spawned)") from None
        if kind == "error":
            exc, tb = payload
            exc.__notes__ = [*getattr(exc, "__notes__", []), f"in the front-end process:\n{tb}"]
            raise exc
        return payload


def _work(frontends: list, inq, outq) -> None:
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):  # as in the pipeline: small matrices
        while True:
            item = inq.get()
            if item is None:
                return
            try:
                if isinstance(item, str) and item == _FINISH:
                    out = {}
                    for fe in frontends:
                        t0 = time.perf_counter()
                        summary = fe.finish(None) if hasattr(fe, "finish") else None
                        out[fe.name] = (summary, time.perf_counter() - t0)
                else:
                    out = {}
                    for fe in frontends:
                        if isinstance(item, tuple(fe.consumes)):
                            t0 = time.perf_counter()
                            obs = fe.process(item, None)
                            out[fe.name] = (obs, time.perf_counter() - t0)
                payload = pickle.dumps(("ok", out))
            except BaseException as exc:  # reported to the caller, which raises it
                try:
                    payload = pickle.dumps(("error", (exc, traceback.format_exc())))
                except Exception:
                    payload = pickle.dumps(("error", (RuntimeError(repr(exc)), traceback.format_exc())))
            outq.put(payload)
