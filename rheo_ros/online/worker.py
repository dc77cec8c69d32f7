"""A worker process that runs an object's methods, called over a pipe.

The estimator node runs its closed forms and its fits each in one of these, off its
own interpreter, so that neither waits for the other nor for message intake (a thread
would share the interpreter's lock with intake). A call is one message each way over
a ``multiprocessing`` pipe and the caller's thread blocks in ``recv`` with the
interpreter's lock released: no executor thread relays it, as ``ProcessPoolExecutor``'s
management thread did. The worker times each computation, so that a caller can tell
the transfer from the work (measured: ~2 ms of a closed form's 27 ms at p50).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from typing import Any


def single_threaded_blas() -> None:
    """BLAS (numpy's and scipy's OpenBLAS) on one thread in this process and those it
    forks: the same bits whatever the machine's cores, so that the node's workers and
    ``rheo analyze`` compute one thing (measured: a bag's analysis JSON differed between
    one and two threads), and no BLAS threads spinning beside the node's message intake
    on a small robot computer (the closed form's p99 at 10 x replay 168 -> 106 ms on 2
    cores). The package's matrices are small; its parallelism is its processes'."""
    import scipy.linalg  # noqa: F401  (loads scipy's own OpenBLAS, so that it is limited too)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


class WorkerDied(RuntimeError):
    """The worker process ended during a call (killed, out of memory); a new one serves
    the next call."""


def _scheduled(realtime: int) -> str:
    """This process under SCHED_FIFO at priority ``realtime`` (0: left as it is); what
    stood in the way, or ""."""
    if realtime <= 0:
        return ""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(realtime))
    except (OSError, AttributeError) as exc:   # no CAP_SYS_NICE, no rtprio limit (EPERM); not Linux
        return (f"real-time priority {realtime} (SCHED_FIFO) refused ({exc.__class__.__name__}: "
                f"{getattr(exc, 'strerror', None) or exc}): normal scheduling")
    return ""


def _serve(conn, target: Any, niceness: int, realtime: int = 0) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # Ctrl-C is the parent's to handle; it stops us
    single_threaded_blas()
    os.nice(niceness)
    refused = _scheduled(realtime)
    prepare = getattr(target, "prepare", None)
    if prepare is not None:
        prepare()
    conn.send(("ready", refused, 0.0))
    while True:
        try:
            request = conn.recv()
        except (EOFError, OSError):   # the parent is gone
            return
        if request is None:
            return
        method, args = request
        start = time.perf_counter()
        try:
            reply = ("ok", getattr(target, method)(*args))
        except Exception as exc:   # the caller raises it; the worker serves on
            reply = ("error", exc)
        conn.send((*reply, time.perf_counter() - start))


class Worker:
    """A process holding ``target`` (its ``prepare()`` run once at start, if it has one);
    ``call(method, *args)`` runs ``target.method(*args)`` there and returns the result or
    raises what it raised; ``last_compute`` is how long the method ran there (s), the
    rest of a call's time being the transfer. One caller thread at a time.

    Args:
        target: a picklable object (sent to the process once).
        niceness: added to the process's nice value (lower priority for long work).
        realtime: SCHED_FIFO priority (1-99) for short work that must not wait for a core
            behind normal processes (needs CAP_SYS_NICE or an rtprio limit; refused, the
            process keeps normal scheduling and ``refused`` says why); 0: none.
    """

    def __init__(self, target: Any, niceness: int = 0, realtime: int = 0) -> None:
        self.target, self.niceness, self.realtime = target, niceness, realtime
        self.refused = ""
        # spawn, not fork: a forked copy of a process running DDS threads is unsafe.
        self._context = multiprocessing.get_context("spawn")
        self._closed = False
        self.last_compute = float("nan")
        self._start()

    def _start(self) -> None:
        self._conn, child = self._context.Pipe()
        self.process = self._context.Process(target=_serve, args=(child, self.target, self.niceness, self.realtime),
                                             daemon=True)
        self.process.start()
        child.close()
        try:   # ready: prepared now, not at the first call
            _, self.refused, _ = self._conn.recv()
        except (EOFError, OSError):
            self.process.join(timeout=1.0)
            raise WorkerDied(f"the worker process ended while starting (exit code {self.process.exitcode})") from None

    def _restart(self) -> int | None:
        """A new process in place of one that ended; the old one's exit code."""
        self._conn.close()
        self.process.join(timeout=1.0)
        code = self.process.exitcode
        self._start()
        return code

    def _receive(self) -> Any:
        try:
            status, value, self.last_compute = self._conn.recv()
        except (EOFError, OSError):
            if self._closed:
                raise WorkerDied("the worker process was stopped") from None
            code = self._restart()
            raise WorkerDied(f"the worker process died (exit code {code}); it was restarted") from None
        if status == "error":
            raise value
        return value

    def call(self, method: str, *args: Any) -> Any:
        """``target.method(*args)`` in the worker process.

        Raises:
            WorkerDied: the process ended before answering (a new one is started).
            Exception: whatever the method raised.
        """
        if self._closed:
            raise WorkerDied("the worker process was stopped")
        try:
            self._conn.send((method, args))
        except OSError:   # it died while idle: the call goes to a new one
            self._restart()
            self._conn.send((method, args))
        return self._receive()

    def close(self, timeout: float = 1.0) -> None:
        """Stop the process: asked to end, then terminated if busy past ``timeout`` s."""
        self._closed = True
        try:
            self._conn.send(None)
        except OSError:
            pass
        self.process.join(timeout)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout)
        self._conn.close()
