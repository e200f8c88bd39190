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

``size`` is the task's rod edges × angle steps × angle (:func:`estimated_size`), so
a sweep over subdivision or steps of one design is ordered too.
"""
from __future__ import annotations

import collections
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
        self._rank = {t.id: i for i, t in enumerate(tasks)}  # the sweep's own order breaks ties
        # per design, its pending tasks largest first: the best task of a design is always its first,
        # so a choice costs O(designs + running), not O(pending)
        self._pending = {}
        for t in sorted(tasks, key=lambda t: -self._size[t.id]):  # stable
            self._pending.setdefault(self.design(t), collections.deque()).append(t)
        self._count = len(tasks)
        self._running = {}   # task id -> (design, start)
        self._rate = {}      # design -> [seconds, size] summed over finished tasks

    def __len__(self) -> int:
        return self._count

    @staticmethod
    def design(task) -> str:
        f = task.params.get("file")
        return f if isinstance(f, str) else ""

    def _key(self, d, task, running_rate):
        """Larger first: (design not started yet, estimated seconds, still unmeasured, earlier in the sweep)."""
        s, rank = self._size[task.id], -self._rank[task.id]
        if d in self._rate:
            seconds, units = self._rate[d]
            return (False, s * seconds / units, False, rank)
        # at least as dear as its running tasks so far (ties go to it: it may well be dearer)
        if d in running_rate:
            return (False, s * running_rate[d], True, rank)
        return (True, s, True, rank)

    def next(self):
        """Remove and return the task to start now (None when none is left)."""
        if not self._count:
            return None
        now = self._clock()
        running_rate = {}
        for i, (d, t0) in self._running.items():
            running_rate[d] = max(running_rate.get(d, 0.0), (now - t0) / self._size[i])
        d = max((d for d, q in self._pending.items() if q), key=lambda d: self._key(d, self._pending[d][0], running_rate))
        task = self._pending[d].popleft()
        self._count -= 1
        self._running[task.id] = (d, now)
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
