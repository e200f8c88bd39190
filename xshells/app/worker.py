"""Long work off the UI thread: one background worker, latest request wins, cancellable.

The UI submits jobs (callables taking a cancel event and a progress
function). Jobs with the same ``key`` supersede each other: a newer slider
position cancels the solve still running for an older one and replaces any
that has not started, so the view always converges to the last request and
the UI thread never waits.
"""
from __future__ import annotations

import threading
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable


@dataclass
class Job:
    fn: Callable[[threading.Event, Callable[[float, str], None]], Any]
    key: str | None = None
    on_done: Callable[[Any], None] | None = None
    on_error: Callable[[BaseException], None] | None = None
    cancel: threading.Event = field(default_factory=threading.Event)


class Worker:
    """A daemon thread running submitted jobs one at a time.

    Parameters
    ----------
    on_progress : callable(fraction, text), optional
        Called from the worker thread as jobs report progress.
    """

    def __init__(self, on_progress: Callable[[float, str], None] | None = None):
        self._cv = threading.Condition()
        self._queue: list[Job] = []
        self._running: Job | None = None
        self._closed = False
        self.on_progress = on_progress
        self.last_error: str | None = None
        self._thread = threading.Thread(target=self._loop, name="xshells-app-worker", daemon=True)
        self._thread.start()

    def submit(self, fn, *, key: str | None = None, on_done=None, on_error=None) -> Job:
        """Queue ``fn(cancel_event, progress)``; a job with the same ``key`` cancels/replaces older ones."""
        job = Job(fn, key, on_done, on_error)
        with self._cv:
            if key is not None:
                self._queue = [j for j in self._queue if j.key != key]
                if self._running is not None and self._running.key == key:
                    self._running.cancel.set()
            self._queue.append(job)
            self._cv.notify_all()
        return job

    def cancel(self, key: str) -> None:
        """Drop queued jobs of ``key`` and ask a running one of ``key`` to stop."""
        with self._cv:
            self._queue = [j for j in self._queue if j.key != key]
            if self._running is not None and self._running.key == key:
                self._running.cancel.set()

    def cancel_all(self) -> None:
        """Drop queued jobs and ask the running one to stop."""
        with self._cv:
            self._queue.clear()
            if self._running is not None:
                self._running.cancel.set()

    @property
    def busy(self) -> bool:
        with self._cv:
            return self._running is not None or bool(self._queue)

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Block until no job is queued or running (for tests and benchmarks)."""
        with self._cv:
            return self._cv.wait_for(lambda: self._running is None and not self._queue, timeout)

    def close(self, timeout: float = 30.0) -> None:
        """Drop queued jobs, cancel the running one and wait (up to ``timeout`` s) for the thread to end.

        Waiting matters at exit: a daemon thread still inside the solver's
        native code when the interpreter shuts down can abort the process.
        """
        with self._cv:
            self._closed = True
            self._queue.clear()
            if self._running is not None:
                self._running.cancel.set()
            self._cv.notify_all()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    def _progress(self, fraction: float, text: str) -> None:
        if self.on_progress is not None:
            try:
                self.on_progress(fraction, text)
            except Exception:  # a UI hiccup must not kill the worker
                pass

    def _loop(self) -> None:
        while True:
            with self._cv:
                self._cv.wait_for(lambda: self._queue or self._closed)
                if self._closed:
                    return
                job = self._running = self._queue.pop(0)
            try:
                result = job.fn(job.cancel, self._progress)
                if job.on_done is not None and not job.cancel.is_set():
                    job.on_done(result)
            except BaseException as exc:  # noqa: BLE001  (reported to the UI, never raised into it)
                self.last_error = "".join(traceback.format_exception_only(type(exc), exc)).strip()
                if job.on_error is not None:
                    try:
                        job.on_error(exc)
                    except Exception:
                        pass
            finally:
                with self._cv:
                    self._running = None
                    self._cv.notify_all()
