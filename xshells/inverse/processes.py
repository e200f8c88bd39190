"""Independent pieces of an inverse design side by side in worker processes, with their progress bars here.

The fan screen's two bisectors and ``--beams auto``'s candidates do not
depend on each other; on the two-core machine this runs on, two at a time
take about half the time. The workers are forked from a fork server
(spawned where there is none), never from this process, which may hold
threads. They ignore Ctrl-C: this process handles it, and asks them to stop
(:class:`RemoteProgress.stopped`), so that a candidate writes its design so
far, as it does when it runs here.

A worker's progress bars are drawn by this process (:class:`BarRelay`): each
update goes through a queue, so that bars of two workers do not overwrite
each other.
"""
from __future__ import annotations

import signal
import threading

_QUEUE = None  # in a worker: the queue its bars' updates go to
_STOP = None   # in a worker: set when this process asks the work to stop


def _init_worker(queue=None, stop=None, rhino_defaults=None, numpy_errors=None):
    global _QUEUE, _STOP
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    follow_numpy_errors(numpy_errors)
    _QUEUE, _STOP = queue, stop
    if rhino_defaults:  # the command's --target-layer etc.: a fork server's worker does not inherit them
        from ..rhino.read import set_defaults

        set_defaults(**rhino_defaults)


class _RemoteBar:
    """The part of a tqdm bar that the inverse design uses, sent to :class:`BarRelay`."""

    def __init__(self, queue, key, total, desc, unit):
        self._q, self._key = queue, key
        queue.put(("open", key, total, desc, unit))

    def update(self, n=1):
        self._q.put(("update", self._key, n))

    def set_postfix(self, **kw):
        self._q.put(("postfix", self._key, {k: str(v) for k, v in kw.items()}))

    def close(self):
        self._q.put(("close", self._key))


class RemoteProgress:
    """In a worker: makes bars drawn by the parent (labelled ``name``), and says when the parent asks to stop."""

    def __init__(self, name: str):
        self.name = name
        self._n = 0

    def bar(self, total, desc, unit="it"):
        if _QUEUE is None:
            return None
        self._n += 1
        return _RemoteBar(_QUEUE, (self.name, self._n), total, f"{self.name}: {desc}", unit)

    def stopped(self) -> bool:
        return _STOP is not None and _STOP.is_set()


class BarRelay:
    """In the parent: draws the workers' bars (tqdm) from the queue, in a thread, until closed."""

    def __init__(self, queue):
        self._q = queue
        self._bars = {}
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        from tqdm import tqdm

        while True:
            msg = self._q.get()
            if msg is None:
                break
            kind, key = msg[0], msg[1]
            if kind == "open":
                self._bars[key] = tqdm(total=msg[2], desc=msg[3], unit=msg[4])
            elif key in self._bars:
                bar = self._bars[key]
                if kind == "update":
                    bar.update(msg[2])
                elif kind == "postfix":
                    bar.set_postfix(**msg[2])
                elif kind == "close":
                    bar.close()
                    del self._bars[key]

    def close(self):
        self._q.put(None)
        self._thread.join(timeout=5)
        for bar in self._bars.values():
            bar.close()


def follow_numpy_errors(errors: dict | None) -> None:
    """In a worker: NumPy's floating-point error handling as the parent's was (``np.geterr()`` there).

    A worker does not inherit it: the command runs under ``np.errstate(all="ignore")`` (the solvers reject
    a trial step whose energy is not finite, and say so), yet its workers printed NumPy's RuntimeWarnings
    (divide by zero in a joint kernel) beside its progress bars."""
    if errors:
        import numpy as np

        np.seterr(**errors)


def mp_context():
    """The multiprocessing context workers start from: a fork server where there is one, else spawn."""
    import multiprocessing as mp

    return mp.get_context("forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn")


def end_pool(pool, wait: bool) -> None:
    """Shut ``pool`` (a ProcessPoolExecutor) down, dropping jobs not started; unless ``wait``, its workers
    are terminated first (they ignore Ctrl-C)."""
    if not wait:
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            if proc.is_alive():
                proc.terminate()
    pool.shutdown(wait=wait, cancel_futures=True)


def in_processes(fn, jobs: list, workers: int, progress: bool = False, stop_wait: float = 0.0):
    """``fn(*job)`` for each job in up to ``workers`` processes; yields ``(job index, result)`` as they finish.

    ``progress``: the workers' :class:`RemoteProgress` bars are drawn here.
    On Ctrl-C (or when the caller gives up) the workers are asked to stop and
    given ``stop_wait`` seconds to finish (a candidate then writes its design
    so far); then they are ended.
    """
    from concurrent.futures import ProcessPoolExecutor, as_completed, wait

    ctx = mp_context()
    queue, stop = (ctx.Queue() if progress else None), ctx.Event()
    relay = BarRelay(queue) if progress else None
    import numpy as np

    from ..rhino.read import get_defaults

    pool = ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx, initializer=_init_worker,
                               initargs=(queue, stop, get_defaults(), np.geterr()))
    done, futures = False, {}
    try:
        futures = {pool.submit(fn, *job): i for i, job in enumerate(jobs)}
        for f in as_completed(futures):
            yield futures[f], f.result()
        done = True
    finally:
        if not done:
            stop.set()
            if stop_wait > 0:
                wait(futures, timeout=stop_wait)
        end_pool(pool, wait=done)
        if relay is not None:
            relay.close()
