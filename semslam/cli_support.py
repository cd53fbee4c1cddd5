"""What every `semslam` command shares, including command groups that plug-ins contribute."""

from __future__ import annotations

import functools
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import typer

from semslam.errors import SemslamError


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``timeout``, a scheduler), raised in the main thread as Ctrl-C raises
    KeyboardInterrupt, so that every cleanup on the way out runs: front-end workers killed,
    a staged output directory removed."""


_RAISES = {signal.SIGINT: KeyboardInterrupt, signal.SIGTERM: Terminated}
# A process stopped by signal N exits with 128 + N, as a shell reports it: 130 (SIGINT), 143 (SIGTERM).
EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}


@contextmanager
def stopped_by_signals(received: list[int]) -> Iterator[None]:
    """Inside the block, SIGINT raises KeyboardInterrupt and SIGTERM :class:`Terminated`, once: a
    further signal while the command cleans up is only noted (the cleanup is short, and a cleanup
    cut half-way is what would leave something behind). ``received`` collects the signals. A signal
    that was ignored when the command started (a background job's SIGINT) stays ignored."""
    if threading.current_thread() is not threading.main_thread():  # handlers belong to the main thread
        yield
        return

    def handler(signum, frame):
        received.append(signum)
        if len(received) == 1:
            raise _RAISES[signum]()

    previous = {sig: signal.getsignal(sig) for sig in _RAISES}
    for sig, old in previous.items():
        if old is not signal.SIG_IGN:
            signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def user_errors(fn):
    """A user error becomes one line on stderr and exit code 1, never a traceback; SIGINT and
    SIGTERM stop the command, its cleanups run, and it exits with 130 / 143 (see
    :func:`stopped_by_signals`)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        received: list[int] = []
        try:
            with stopped_by_signals(received):
                return fn(*args, **kwargs)
        except BaseException as exc:
            if received or isinstance(exc, KeyboardInterrupt):  # whatever the signal interrupted
                signum = received[0] if received else signal.SIGINT
                message, code = f"stopped by {signal.Signals(signum).name}", EXIT_CODES[signum]
            elif isinstance(exc, SemslamError):
                message, code = f"error: {exc}", 1
            else:
                raise
        # Out of the except block, so that nothing keeps the failed run's frames (and their worker
        # queues, whose semaphores the resource tracker would report as leaked) alive until exit.
        typer.echo(f"semslam: {message}", err=True)
        raise typer.Exit(code)

    return wrapper


MissionArg = typer.Argument(..., help="ROS 1 .bag, ROS 2 bag directory or .mcap")
ConfigOpt = typer.Option(None, "--config", "-c", help="YAML configuration (see `semslam config dump`)")
