"""Which task a free worker gets next: the most expensive first, costs learnt as the sweep runs.

With the dearest tasks first, the cheap ones fill the workers' last gaps
(longest-processing-time-first list scheduling). A task's cost is not known
before it runs: whether a design buckles, and how often, decides it more
than its size does (the bundled sweep's irregular grid has fewer segments
than the regular one and costs 3.5 times as much per task). So the order is
decided one task at a time, as workers free up:

1. a design (a task's ``file``) that has not started yet goes first, the
   largest first: one task of each design measures it;
2. then the task with the largest estimated time: ``size × (mean seconds
   per unit of size)`` over its design's finished tasks, or, while none
   has finished, the time its running tasks have taken so far (a lower
   bound, preferred on a tie: it may well be dearer).

``size`` is the task's rod edges × angle steps (:func:`estimated_size`), so
a sweep over subdivision or steps of one design is ordered too.
"""
from __future__ import annotations

import time


class DispatchOrder:
    """Pending tasks and what their designs cost so far.

    Parameters
    ----------
    tasks : sequence of Task
        The tasks to run (each with ``id`` and ``params``).
    size : dict
        Task id -> estimated size (0 when unknown).
    clock : callable
        Seconds, monotonic (``time.perf_counter``; a test passes its own).
    """

    def __init__(self, tasks, size: dict, clock=time.perf_counter):
        self._clock = clock
        self._size = {t.id: max(float(size.get(t.id, 0)), 1.0) for t in tasks}
        # stable: equal keys keep the sweep's own order
        self._pending = sorted(tasks, key=lambda t: -self._size[t.id])
        self._running = {}   # task id -> (design, start)
        self._rate = {}      # design -> [seconds, size] summed over finished tasks

    def __len__(self) -> int:
        return len(self._pending)

    @staticmethod
    def design(task) -> str:
        f = task.params.get("file")
        return f if isinstance(f, str) else ""

    def _key(self, task, now):
        """Larger first: (design not started yet, estimated seconds, still unmeasured)."""
        d, s = self.design(task), self._size[task.id]
        if d in self._rate:
            seconds, units = self._rate[d]
            return (False, s * seconds / units, False)
        # at least as dear as its running tasks so far (ties go to it: it may well be dearer)
        rates = [(now - t0) / self._size[i] for i, (dd, t0) in self._running.items() if dd == d]
        if rates:
            return (False, s * max(rates), True)
        return (True, s, True)

    def next(self):
        """Remove and return the task to start now (None when none is left)."""
        if not self._pending:
            return None
        now = self._clock()
        best = max(range(len(self._pending)), key=lambda i: (self._key(self._pending[i], now), -i))
        task = self._pending.pop(best)
        self._running[task.id] = (self.design(task), now)
        return task

    def finished(self, task, seconds: float | None = None) -> None:
        """Record that ``task`` ended, after ``seconds`` of work (default: since it was handed out)."""
        d, t0 = self._running.pop(task.id, (self.design(task), None))
        if seconds is None or seconds <= 0:
            if t0 is None:
                return
            seconds = self._clock() - t0
        acc = self._rate.setdefault(d, [0.0, 0.0])
        acc[0] += seconds
        acc[1] += self._size[task.id]
