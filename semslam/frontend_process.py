"""Front-ends that do not read the estimate, run in processes of their own.

A front-end that declares ``uses_view = False`` (it never reads the ``EstimateView``: the laser
takes "up" from the AHRS, the oracle reads ground truth) depends on nothing but the measurements,
so it can work a few scans ahead while the estimators work through the measurements before them.

The front-ends are pickled into worker processes and fed the measurements they consume, in order;
they keep their state there. Results come back in the same order: the observations of each
front-end and the time it took. Payloads are pickled in the worker, so that an object that cannot
cross (or any exception) is reported to the caller instead of hanging a queue's feeder thread.

Where each front-end runs:

- A sequential front-end (no ``parallel_consumes``) lives in one worker, its home (the sequential
  ones are spread over the workers), and gets there every measurement it consumes.
- A front-end whose result for some measurement types depends only on that measurement and on what
  it kept from its other types (``parallel_consumes``: the laser's scans, given the latest AHRS
  reading) has a replica in every worker. Its parallel measurements go to one replica each, the
  one with the least work waiting (:class:`_Balance`); its other types go to every replica (so that each keeps the same state), and nobody
  answers for them: the estimators go on without waiting (the laser's 9800 AHRS readings). A
  replica's ``finish()`` must not depend on the parallel measurements (the first one's is used).

The results of one measurement may so come from several workers (the laser's from the replica
whose turn it was, a sequential front-end's from its home); they are merged, and the driver feeds
them in the front-ends' order. Measurements no worker answers for travel in batches, pickled once
for all the workers, ahead of the next measurement that is answered (one queue item per worker
instead of one per reading and worker: ~1.2 s of CPU on the tank mission, 2 workers).

Start: a fork of this process would inherit its OpenMP and GTSAM threads, so the workers are forked
from multiprocessing's fork server instead, a fresh interpreter (no threads) that has imported the
front-ends' modules once (``set_forkserver_preload``): a spawned worker imported them itself (open3d
and all, ~2.2 s of CPU each before its first message); a forked one starts in ~0.25 s, after the
server's ~2.1 s once per process. The server lives until this process exits, with the environment
it started with: each worker is handed this process's environment as it is when the worker is
created (a front-end may read it at use, e.g. the recogniser's cache folder).

Stop: workers never outlive the run, whatever ends it. A normal end lets them finish and exit; an
exception (an error, Ctrl-C, SIGTERM turned into an exception by the CLI) kills them at once
(:meth:`FrontendProcess.abort`). The caller's SIGINT and SIGTERM reach the workers even while the
caller's thread is deep in a GTSAM call that holds the GIL for seconds: the caller's signal wake-up
fd is one end of a socket pair, written by the C-level handler the moment the signal arrives, and
each worker watches the other end in a thread of its own (``_stop_with_parent``). The same socket
at end of file means the caller is gone (killed, crashed): the worker exits too, and the fork
server and multiprocessing's resource tracker, which live while any worker holds their pipes,
follow. Workers ignore SIGINT themselves: the caller decides (a Ctrl-C reaches the whole process
group; a worker that turned it into an error reply kept the run alive for 20 s).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import queue
import signal
import socket
import tempfile
import threading
import time
import traceback
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.connection import wait

from semslam.determinism import one_thread_per_library
from semslam.errors import SemslamError
from semslam.mission.measurements import Measurement
from semslam.registry import Frontend

WORKER_NICE = 10
_STATE_BATCH = 256  # measurements nobody answers for, sent at the latest after this many
_STOP_SIGNALS = frozenset((signal.SIGINT, signal.SIGTERM))
_START_WAIT_S = 10.0  # an aborted run waits this long at most for a worker's start under way
_ALIVE_CHECK_S = 0.5  # a worker that died without a word is noticed this soon (a timed-out get costs nothing)


def runs_in_process(frontend) -> bool:
    """A :class:`~semslam.registry.Frontend` that never reads the estimate (``uses_view = False``)."""
    return isinstance(frontend, Frontend) and not frontend.uses_view


def parallel_types(frontend) -> tuple[type, ...]:
    """The measurement types a front-end takes in parallel (``parallel_consumes``; none by default)."""
    return tuple(frontend.parallel_consumes)


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
    modules = {__name__, "threadpoolctl", "tqdm"} | {type(fe).__module__ for fe in frontends}
    modules.discard("__main__")
    ctx.set_forkserver_preload(sorted(modules))
    return ctx


@dataclass(frozen=True)
class _Route:
    """Where a measurement type goes: ``parallel`` — the replicated front-ends that take it in
    parallel (one replica, in turn); ``everywhere`` — some replicated front-end keeps state from it
    (every worker); ``sequential`` — the sequential front-ends that consume it, with their homes."""

    parallel: tuple[str, ...]
    everywhere: bool
    sequential: tuple[tuple[str, int], ...]

    @property
    def turn(self) -> bool:
        return bool(self.parallel)

    @property
    def homes(self) -> frozenset[int]:
        return frozenset(w for _, w in self.sequential)

    @property
    def answered(self) -> bool:
        return self.turn or bool(self.sequential)


class _Balance:
    """Whose turn a parallel measurement is: the worker with the least work submitted and not yet
    answered, counting the sequential front-ends' share of the same measurement, as estimated from
    each front-end's mean seconds per answered measurement of that type so far (unknown: one unit
    each; ties in turn, so equal workers alternate). Plain turns gave the laser odometry's worker half
    the laser's scans as well: 2.3x the other worker's work on the tank (issue 23); so did a mean over
    all of a front-end's types, which its cheap AHRS, DVL and depth readings brought near zero."""

    _UNKNOWN = 1.0
    _KEEP = 0.8  # weight of the old mean: a front-end's cost drifts with the scene

    def __init__(self, n_workers: int):
        self._busy = [0.0] * n_workers  # estimated seconds submitted to each worker, not yet answered
        self._cost: dict[tuple[str, type], float] = {}  # (front-end, measurement type) → mean seconds
        self._next = 0

    def place(self, route: _Route, kind: type) -> tuple[int | None, dict[int, float]]:
        """The turn for a measurement of type ``kind`` (None if no front-end takes it in parallel) and
        each answering worker's estimated load."""
        load: dict[int, float] = {}
        for name, home in route.sequential:
            load[home] = load.get(home, 0.0) + self._estimate(name, kind)
        turn = None
        if route.parallel:
            n = len(self._busy)
            turn = min(range(n), key=lambda w: (self._busy[w] + load.get(w, 0.0), (w - self._next) % n))
            self._next = (turn + 1) % n
            load[turn] = load.get(turn, 0.0) + sum(self._estimate(name, kind) for name in route.parallel)
        for w, c in load.items():
            self._busy[w] += c
        return turn, load

    def _estimate(self, name: str, kind: type) -> float:
        return self._cost.get((name, kind), self._UNKNOWN)

    def answered(self, load: dict[int, float], kind: type, seconds: dict[str, float]) -> None:
        for w, c in load.items():
            self._busy[w] -= c
        for name, dt in seconds.items():
            old = self._cost.get((name, kind))
            self._cost[name, kind] = dt if old is None else self._KEEP * old + (1 - self._KEEP) * dt


@dataclass(frozen=True)
class _Finish:
    """The end of the mission; a worker answers with the summaries of ``names`` (its other
    front-ends' time only)."""

    names: tuple[str, ...]


class FrontendProcess:
    """Worker processes running ``frontends`` on the measurements submitted to them; results in
    submission order. ``workers`` > 1 helps front-ends that declare ``parallel_consumes``, and
    several sequential front-ends (one home each)."""

    def __init__(self, frontends: Sequence[Frontend], workers: int = 1):
        ctx = _context(frontends)
        self.names = [fe.name for fe in frontends]
        self._types = [tuple(fe.consumes) for fe in frontends]
        self._parallel = [parallel_types(fe) for fe in frontends]
        sequential = [i for i, par in enumerate(self._parallel) if not par]
        n = max(1, workers) if any(self._parallel) else max(1, min(workers, len(sequential)))
        self._home = {i: k % n for k, i in enumerate(sequential)}  # a sequential front-end's worker
        self._routes: dict[type, _Route] = {}
        # which workers answer each submitted measurement, and the load it was estimated to give them
        self._owners: deque[tuple[tuple[int, ...], dict[int, float], type]] = deque()
        self._balance = _Balance(n)
        self._state: list[Measurement] = []  # measurements nobody answers for, not yet sent
        self._relay = _SignalRelay()
        self._workers: list[_Worker] = []
        try:
            for w in range(n):
                mine = [fe for i, fe in enumerate(frontends) if self._home.get(i, w) == w]
                self._workers.append(_Worker(ctx, mine, w, self._relay.worker_end))
        except BaseException:
            self.abort()
            raise

    def consumes(self, m: Measurement) -> bool:
        """Whether some front-end of the process takes ``m`` (its type's route, worked out once)."""
        route = self._route(m)
        return route.answered or route.everywhere

    def _route(self, m: Measurement) -> _Route:
        route = self._routes.get(type(m))
        if route is None:
            takers = [
                (i, par) for i, (types, par) in enumerate(zip(self._types, self._parallel)) if isinstance(m, types)
            ]
            route = self._routes[type(m)] = _Route(
                parallel=tuple(self.names[i] for i, par in takers if par and isinstance(m, par)),
                everywhere=any(par and not isinstance(m, par) for _, par in takers),
                sequential=tuple((self.names[i], self._home[i]) for i, par in takers if not par),
            )
        return route

    def submit(self, m: Measurement) -> bool:
        """Send ``m`` to the workers; True if a result will come back for it (see :meth:`result`)."""
        route = self._route(m)
        if not route.answered:  # state only, for every replica
            self._state.append(m)
            if len(self._state) >= _STATE_BATCH:
                self._send_state()
            return False
        self._send_state()
        turn, load = self._balance.place(route, type(m))
        answering = route.homes | ({turn} if turn is not None else set())
        for w in self._workers:
            if route.everywhere or w.index in answering:
                w.send((m, w.index == turn), reply=w.index in answering)
        self._owners.append((tuple(sorted(answering)), load, type(m)))
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
        out: dict[str, tuple[list, float]] = {}
        workers, load, kind = self._owners.popleft()
        for w in workers:
            for name, (obs, dt) in self._workers[w].receive(self.names).items():
                before, t = out.get(name, ([], 0.0))  # a replica keeping state answers with nothing
                out[name] = (before + obs, t + dt)
        self._balance.answered(load, kind, {name: dt for name, (_, dt) in out.items()})
        return out

    def finish(self) -> dict[str, tuple[object, float]]:
        """Every front-end's ``finish()`` summary (None without one) and its time in every worker
        (the summary of a replicated front-end is its first replica's)."""
        self._send_state()
        summarised = [
            tuple(name for i, name in enumerate(self.names) if self._home.get(i, 0) == w.index) for w in self._workers
        ]
        for w, names in zip(self._workers, summarised):
            w.send(_Finish(names), reply=True)
        out: dict[str, tuple[object, float]] = {}
        for w, names in zip(self._workers, summarised):
            for name, (summary, dt) in w.receive(self.names).items():
                before, t = out.get(name, (None, 0.0))
                out[name] = (summary if name in names else before, t + dt)
        return out

    def close(self) -> None:
        """After :meth:`finish`: let the workers exit."""
        for w in self._workers:  # all told first: their exits overlap (~0.5 s each, open3d and all)
            w.stop()
        for w in self._workers:
            w.close()
        self._relay.close()

    def abort(self) -> None:
        """Kill the workers now (an error or a signal ends the run: their work is of no use)."""
        for w in self._workers:
            w.kill()
        for w in self._workers:
            w.close(timeout=2.0)
        self._relay.close()


class _SignalRelay:
    """A socket pair: this process's end is its signal wake-up fd (Python's C-level handler writes
    the signal's number there the moment a signal with a Python handler arrives, whatever the main
    thread is doing); the workers watch the other end (:func:`_stop_with_parent`), which also reads
    end-of-file once this process has closed or lost its end. The wake-up fd is taken only from the
    main thread and only when nobody else uses it (asyncio does): otherwise the workers still stop
    when this process ends or kills them, just not at the moment of the signal."""

    def __init__(self):
        self._ours, self.worker_end = socket.socketpair()
        self._ours.setblocking(False)
        self._installed = False
        try:
            previous = signal.set_wakeup_fd(self._ours.fileno(), warn_on_full_buffer=False)
        except ValueError:  # not the main thread
            return
        if previous != -1:
            signal.set_wakeup_fd(previous)
        else:
            self._installed = True

    def close(self) -> None:
        self.worker_end.close()
        if self._installed:
            try:
                signal.set_wakeup_fd(-1)
            except ValueError:  # not the main thread: keep our end open rather than let the handler
                return  # write into whatever file reuses its number
            self._installed = False
        self._ours.close()


class _Worker:
    def __init__(self, ctx, frontends: list, index: int, relay: socket.socket):
        self.index = index
        self._in = ctx.Queue()
        self._out = ctx.Queue()
        self._proc = ctx.Process(
            target=_work,
            args=(frontends, self._in, self._out, dict(os.environ), relay),
            daemon=True,
            name=f"semslam-frontends-{index}",
        )
        # Started aside: a forkserver's start waits for its child's pid, i.e. for the server to have
        # imported the front-ends (~2 s, once per process), while the caller could be reading the
        # mission. Measurements sent meanwhile wait in the queue.
        self._start_error: BaseException | None = None
        self._lock = threading.Lock()
        self._started_flag = self._killed = False
        self._starter: threading.Thread | None = threading.Thread(
            target=self._start, daemon=True, name=f"semslam-frontends-start-{index}"
        )
        self._starter.start()

    def _start(self) -> None:
        try:
            self._proc.start()
        except BaseException as exc:  # raised in the caller's thread by _started()
            self._start_error = exc
        with self._lock:
            self._started_flag = True
            if self._killed and self._start_error is None:  # killed while it started
                self._proc.kill()

    def _started(self) -> None:
        """Wait for the process to have started; raise what starting it raised."""
        if self._starter is not None:
            self._starter.join()
            self._starter = None
        if isinstance(self._start_error, OSError):  # e.g. a TMPDIR too long for the fork server's socket
            raise SemslamError(
                f"cannot start a front-end process ({self._start_error}); its fork server's socket goes in "
                f"{tempfile.gettempdir()} (TMPDIR)"
            ) from None
        if self._start_error is not None:
            raise self._start_error

    def send(self, item, reply: bool) -> None:
        self._in.put((item, reply))

    def receive(self, names: list[str]):
        self._started()
        while True:
            try:
                kind, payload = pickle.loads(self._out.get(timeout=_ALIVE_CHECK_S))
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

    def kill(self) -> None:
        """SIGKILL now, or as soon as a start under way has its pid."""
        with self._lock:
            self._killed = True
            if self._started_flag and self._start_error is None:
                self._proc.kill()

    def close(self, timeout: float = 10.0) -> None:
        if self._starter is not None:
            # Even when killed: a start under way ends first (and _start kills the new worker). Left
            # to itself, the fork server would fork the worker after this process's queues are gone
            # and it would die unpickling them, with a traceback on the user's terminal.
            self._starter.join(timeout=_START_WAIT_S if self._killed else None)
        if self._started_flag and self._start_error is None:
            self._proc.join(timeout=timeout)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(timeout=1.0)
        # Measurements still queued for a dead worker can never be read: without this, the queue's
        # feeder thread blocks on the full pipe and the interpreter hangs at exit.
        self._in.cancel_join_thread()
        self._in.close()
        self._out.close()


def _stop_with_parent(relay: socket.socket) -> None:
    """Exit this worker the moment the parent gets SIGINT or SIGTERM (its wake-up fd writes the
    signal's number into the relay) or is gone (the relay at end of file); see :class:`_SignalRelay`.
    The bytes are only peeked at: every worker reads the same ones."""

    def watch():
        while True:
            wait([relay])
            try:
                got = relay.recv(256, socket.MSG_PEEK)
            except OSError:
                got = b""
            if not got or _STOP_SIGNALS & set(got):
                os._exit(1)
            time.sleep(0.1)  # another signal with a Python handler: the parent deals with it

    threading.Thread(target=watch, daemon=True, name="semslam-parent-watch").start()


def _work(frontends: list, inq, outq, environ: dict[str, str], relay: socket.socket) -> None:
    from tqdm import tqdm

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides (and tells, see _stop_with_parent)
    _stop_with_parent(relay)
    # tqdm's default lock is a named semaphore, which a killed worker would leave to the resource
    # tracker (and its "leaked semaphore" warning); a worker's bars need only a thread lock.
    tqdm.set_lock(threading.RLock())
    # The caller's environment now, not the fork server's (frozen when the server started).
    os.environ.clear()
    os.environ.update(environ)

    # Below the estimators' priority: they consume the results in order, so on a machine with
    # fewer cores than processes a worker should take the CPU they leave, not the reverse.
    os.nice(WORKER_NICE)

    unreported: dict[str, float] = {}  # time spent on measurements without a reply, told with the next

    def keep_time(out: dict) -> None:
        for name, (_, dt) in out.items():
            unreported[name] = unreported.get(name, 0.0) + dt

    with one_thread_per_library():  # as in the pipeline: the same results on any machine
        while True:
            msg = inq.get()
            if msg is None:
                return
            item, reply = msg
            try:
                if isinstance(item, bytes):  # a batch of state-only measurements (no reply)
                    for m in pickle.loads(item):
                        keep_time(_process(frontends, m, turn=False))
                    continue
                if isinstance(item, _Finish):
                    out = _finish(frontends, item.names)
                    out.update({name: (None, 0.0) for name in unreported if name not in out})
                else:
                    out = _process(frontends, *item)
                    if not reply:  # a replica keeping its state: another worker answers, if anyone
                        keep_time(out)
                        continue
                out = {name: (o, dt + unreported.pop(name, 0.0)) for name, (o, dt) in out.items()}
                payload = pickle.dumps(("ok", out))
            except BaseException as exc:  # reported to the caller, which raises it
                try:
                    payload = pickle.dumps(("error", (exc, traceback.format_exc())))
                except Exception:
                    payload = pickle.dumps(("error", (RuntimeError(repr(exc)), traceback.format_exc())))
            outq.put(payload)


def _process(frontends: list, m: Measurement, turn: bool) -> dict[str, tuple[list, float]]:
    """Front-end name → (observations, seconds) of one measurement, for this worker's front-ends
    that consume it; a replicated front-end takes a measurement of its parallel types only in its
    ``turn``."""
    out = {}
    for fe in frontends:
        if not isinstance(m, tuple(fe.consumes)):
            continue
        par = parallel_types(fe)
        in_parallel = bool(par) and isinstance(m, par)
        if in_parallel and not turn:
            continue
        t0 = time.perf_counter()
        obs = fe.process(m, None)
        out[fe.name] = (obs, time.perf_counter() - t0)
        if obs and par and not in_parallel:
            raise RuntimeError(
                f"front-end {fe.name!r} observed on a {type(m).__name__}, which it "
                "does not take in parallel: with parallel_consumes, its other "
                "measurement types may only feed its state"
            )
    return out


def _finish(frontends: list, names: tuple[str, ...]) -> dict[str, tuple[object, float]]:
    """Front-end name → (summary, seconds) of ``finish()`` for this worker's front-ends in ``names``."""
    out = {}
    for fe in frontends:
        if fe.name in names:
            t0 = time.perf_counter()
            summary = fe.finish(None)
            out[fe.name] = (summary, time.perf_counter() - t0)
    return out
