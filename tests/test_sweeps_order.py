"""Dispatch order of a sweep's tasks (xshells.sweeps.order): dearest first, costs learnt as they finish."""
from __future__ import annotations

import heapq

from xshells.sweeps.order import DispatchOrder
from xshells.sweeps.spec import Task


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def tasks(*designs):
    return [task(f"t{i}", d, i) for i, d in enumerate(designs)]


def task(id_, design, index=0):
    return Task(id_, index, {"file": design}, {})


def test_each_design_starts_once_before_any_repeats_largest_first():
    ts = tasks("a", "a", "b", "b", "c")
    order = DispatchOrder(ts, {"t0": 10, "t1": 10, "t2": 30, "t3": 30, "t4": 20}, clock=Clock())
    first = [order.next().params["file"] for _ in range(3)]
    assert first == ["b", "c", "a"]


def test_an_unmeasured_running_design_counts_at_least_its_time_so_far():
    clock = Clock()
    ts = tasks("cheap", "dear", "cheap", "dear")
    order = DispatchOrder(ts, {t.id: 100 for t in ts}, clock=clock)
    a, b = order.next(), order.next()
    assert {a.params["file"], b.params["file"]} == {"cheap", "dear"}
    clock.now = 1.0
    order.finished(a if a.params["file"] == "cheap" else b, 1.0)
    # "dear" has run 1 s and is still running; "cheap" is known to take 1 s: the tie goes to "dear"
    assert order.next().params["file"] == "dear"


def test_measured_designs_ordered_by_size_times_rate():
    clock = Clock()
    ts = tasks("a", "b", "a", "b", "b")
    size = {"t0": 10, "t1": 10, "t2": 40, "t3": 10, "t4": 30}
    order = DispatchOrder(ts, size, clock=clock)
    # t2 (a, 40) and t4 (b, 30) are the largest of their designs and go first
    started = {order.next().id, order.next().id}
    assert started == {"t2", "t4"}
    order.finished(task("t2", "a"), 4.0)   # a: 0.1 s per unit
    order.finished(task("t4", "b"), 30.0)  # b: 1 s per unit
    # left: t0 (a, 10 -> 1 s), t1 (b, 10 -> 10 s), t3 (b, 10 -> 10 s)
    assert [order.next().id for _ in range(3)] == ["t1", "t3", "t0"]
    assert order.next() is None


def makespan(costs: dict, designs: list, workers: int, ordered: bool) -> float:
    """List scheduling of the tasks on ``workers``, in the given order or by DispatchOrder."""
    clock = Clock()
    ts = tasks(*designs)
    order = DispatchOrder(ts, {t.id: 1 for t in ts}, clock=clock)
    queue = list(ts)
    free = [(0.0, w) for w in range(workers)]
    end = 0.0
    running = []
    while queue if not ordered else len(order):
        t, w = heapq.heappop(free)
        clock.now = t
        while running and running[0][0] <= t:  # report what finished by now
            done_t, _, task = heapq.heappop(running)
            order.finished(task, costs[task.params["file"]])
        task = order.next() if ordered else queue.pop(0)
        finish = t + costs[task.params["file"]]
        heapq.heappush(running, (finish, task.id, task))
        heapq.heappush(free, (finish, w))
        end = max(end, finish)
    return end


def test_the_bundled_sweep_shape_is_balanced():
    # sweep_example.yaml: the regular grid's tasks (1.2 s) come first in the spec, the irregular
    # grid's (4.5 s, fewer segments) last; in spec order the dear tasks end the sweep
    costs = {"uniform": 1.2, "nonuniform": 4.5}
    designs = ["uniform"] * 4 + ["nonuniform"] * 4
    ideal = sum(costs[d] for d in designs) / 2
    learnt = makespan(costs, designs, 2, ordered=True)
    assert learnt <= ideal + 1.2 + 1e-9  # the dear tasks first: at most one cheap task of imbalance
    # and it beats spec order when the dear tasks' count is odd per worker
    designs = ["uniform"] * 5 + ["nonuniform"] * 3
    assert makespan(costs, designs, 2, ordered=True) < makespan(costs, designs, 2, ordered=False)
