"""Threads for the panels: long work off the kernel's main thread, results back onto it.

Why: a widget callback that meshes or trains for seconds blocks the kernel, so slider moves
pile up and Stop cannot be pressed.  Work runs on a background thread; what touches VTK
(renders) must run on the main thread (VTK renders black frames from JupyterLab's subshell
threads), so it is sent back through the
asyncio loop the kernel runs (``loop.call_soon_threadsafe``).  Without a running loop (plain
scripts, pytest) such calls are queued and run by :meth:`MainThread.drain`.
"""

from __future__ import annotations

import asyncio
import queue
import threading
import time
from collections.abc import Callable
from typing import Any


class MainThread:
    """Run callables on the main thread: directly, through the kernel's loop, or queued."""

    def __init__(self) -> None:
        try:
            self.loop: asyncio.AbstractEventLoop | None = asyncio.get_running_loop()
        except RuntimeError:
            self.loop = None
        self._queue: queue.SimpleQueue = queue.SimpleQueue()

    @property
    def has_loop(self) -> bool:
        return self.loop is not None and self.loop.is_running() and not self.loop.is_closed()

    def call(self, fn: Callable, *args: Any, vtk: bool = True) -> None:
        """Call ``fn(*args)`` on the main thread (now if already there).

        With no running loop: ``vtk=True`` calls are queued for :meth:`drain`; others run
        at once on the calling thread (widget traits and numpy data are thread-safe enough).
        """
        if threading.current_thread() is threading.main_thread():
            fn(*args)
        elif self.has_loop:
            self.loop.call_soon_threadsafe(fn, *args)
        elif vtk:
            self._queue.put((fn, args))
        else:
            fn(*args)

    def drain(self) -> int:
        """Run the queued calls (main thread only); return how many ran."""
        n = 0
        while True:
            try:
                fn, args = self._queue.get_nowait()
            except queue.Empty:
                return n
            fn(*args)
            n += 1


class LatestWorker:
    """Compute only the newest job on a background thread; jobs superseded while busy are dropped.

    ``submit(job, followup=None)``: when ``followup`` is given and no newer job arrives within
    ``settle`` seconds after ``job`` is delivered, ``followup`` runs (a full-resolution mesh after
    a preview made while a slider is dragged).  ``deliver(job, result, error)`` runs on the main
    thread; with a running loop the worker waits for it before the next job (so renders never
    queue up behind each other, and the next job's computing does not take the CPU from drawing
    and sending the last result).
    :attr:`superseded` is set while a newer job waits: a followup's compute can pass it on as its
    stop flag (its result is then dropped, never delivered).
    """

    def __init__(self, compute: Callable, deliver: Callable, main: MainThread, settle: float = 0.3):
        self.compute, self.deliver, self.main, self.settle = compute, deliver, main, settle
        self._cond = threading.Condition()
        self._pending: tuple[Any, Any] | None = None
        self._busy = False
        self._thread: threading.Thread | None = None
        self.superseded = threading.Event()  # a newer job is waiting
        self.dropped = 0  # jobs replaced before they started (coalesced moves), or stopped followups

    def submit(self, job: Any, followup: Any = None) -> None:
        with self._cond:
            if self._pending is not None:
                self.dropped += 1
            self._pending = (job, followup)
            self.superseded.set()
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._run, name="pyfrep-remesh", daemon=True)
                self._thread.start()
            self._cond.notify_all()

    def _next(self) -> tuple[Any, Any] | None:
        with self._cond:
            while self._pending is None:
                if not self._cond.wait(timeout=60.0):
                    self._thread = None  # idle for a minute: let the thread end
                    return None
            item, self._pending = self._pending, None
            self.superseded.clear()
            self._busy = True
            return item

    def _settled(self) -> bool:
        """Wait ``settle`` seconds; True when no newer job came meanwhile."""
        with self._cond:
            end = time.monotonic() + self.settle
            while self._pending is None and (left := end - time.monotonic()) > 0:
                self._cond.wait(timeout=left)
            return self._pending is None

    def _run(self) -> None:
        while (item := self._next()) is not None:
            job, followup = item
            self._one(job)
            # a followup may name its own (a dict's "then"): stages run in turn until a newer job comes
            while followup is not None and self._settled():
                then = followup.get("then") if isinstance(followup, dict) else None
                self._one(followup, stoppable=True)
                if self.superseded.is_set():
                    break
                followup = then
            with self._cond:
                self._busy = False
                self._cond.notify_all()

    def _one(self, job: Any, stoppable: bool = False) -> None:
        result, error = None, None
        try:
            result = self.compute(job)
        except Exception as err:  # shown in the panel's status line, never lost
            error = err
        if stoppable and self.superseded.is_set():  # stopped, or outdated: the newer job is shown instead
            self.dropped += 1
            return
        done = threading.Event()

        def deliver() -> None:
            try:
                self.deliver(job, result, error)
            finally:
                done.set()

        self.main.call(deliver)
        if self.main.has_loop:
            done.wait(timeout=30.0)

    def run_now(self, job: Any) -> None:
        """Compute ``job`` in the calling thread and deliver it there (no event loop: tests, scripts)."""
        try:
            result = self.compute(job)
        except Exception as err:  # shown in the panel's status line, never lost
            self.deliver(job, None, err)
            return
        self.deliver(job, result, None)

    def idle(self) -> bool:
        with self._cond:
            return self._pending is None and not self._busy

    def wait(self, timeout: float = 120.0) -> None:
        """Block until no job is pending or running, then run queued main-thread calls."""
        end = time.monotonic() + timeout
        with self._cond:
            while self._pending is not None or self._busy:
                left = end - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"background work still running after {timeout} s")
                self._cond.wait(timeout=min(left, 0.05))
        self.main.drain()


class BackgroundRun:
    """One long run (training, fitting) on a thread, with a Stop flag and a completion hook.

    ``target(stop)`` runs on the thread; ``done(result, error)`` runs on the main thread.
    """

    def __init__(self, target: Callable[[threading.Event], Any], done: Callable, main: MainThread):
        self.stop = threading.Event()
        self.main = main
        self.result: Any = None
        self.error: BaseException | None = None
        self._done = done
        self._thread = threading.Thread(target=self._run, args=(target,), name="pyfrep-run", daemon=True)

    def start(self) -> BackgroundRun:
        self._thread.start()
        return self

    def _run(self, target: Callable) -> None:
        try:
            self.result = target(self.stop)
        except Exception as err:
            self.error = err
        self.main.call(self._done, self.result, self.error)

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def wait(self, timeout: float = 300.0) -> Any:
        """Join the thread and run queued main-thread calls; the error, if any, is in ``.error``."""
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise TimeoutError(f"run still going after {timeout} s")
        self.main.drain()
        return self.result
