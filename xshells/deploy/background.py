"""Output files written by forked processes on the other core while the command goes on.

``xshells deploy`` writes its flat state's files (meshes, picture, drawings)
while it deploys, and its deployed state's pictures, Rhino file and
fabrication files while it writes the meshes: a :class:`Background` is a
child process forked from the command, which runs a first job on what it
inherited (the solved state, by copy-on-write), imports the modules of later
jobs, forks its sibling lanes from there (sharing those modules), and then
each lane runs the jobs sent to it, in order. :meth:`Background.join` waits
for them and raises the first error met (with its traceback as a note), so
that a command still fails on a file it could not write.

The children ignore SIGINT and SIGTERM: Ctrl-C at a terminal reaches the
whole process group, and the command (which keeps what is finished, every
file complete or absent) waits for its writers before it writes
``result.json``. Each file is written atomically (a temporary name, then a
rename), as inline.

Where ``os.fork`` is missing (Windows), or ``inline=True``, the jobs run in
the calling process at once, with the same results. A writer only helps where
a core would otherwise idle: on a machine that other work keeps busy it takes
CPU from the solve (the manta ray with another process on one of 2 cores: deploy
phase 2.57 -> 3.56 s, the whole run 4.69 -> 4.99 s), so the command asks
:class:`IdleCores` first.
"""
from __future__ import annotations

import os
import pickle
import signal
import struct
import sys
import traceback
from collections.abc import Callable, Sequence

_HEADER = struct.Struct("<Q")
# The parent's ends of every live writer's pipes: a writer forked later closes them, else it would hold
# an earlier writer's job pipe open, and that writer would never see the end of its jobs.
_PARENT_FDS: set[int] = set()


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _read_exactly(fd: int, n: int) -> bytes | None:
    chunks, left = [], n
    while left:
        chunk = os.read(fd, min(left, 1 << 20))
        if not chunk:
            return None
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def _send(fd: int, obj) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    _write_all(fd, _HEADER.pack(len(data)) + data)


def _receive(fd: int):
    head = _read_exactly(fd, _HEADER.size)
    if head is None:
        return None
    data = _read_exactly(fd, _HEADER.unpack(head)[0])
    return None if data is None else pickle.loads(data)


class IdleCores:
    """How many cores idled since this object was made (``/proc/stat``; Linux), to decide on a writer.

    Made when a command starts and asked when it would fork (after its imports and
    rest-length solve, about half a second, one core busy with them).
    """

    def __init__(self):
        self._start = self._read()

    @staticmethod
    def _read():
        try:
            with open("/proc/stat") as f:
                head = f.readline().split()
            ticks = [int(v) for v in head[1:]]
            return sum(ticks), ticks[3] + (ticks[4] if len(ticks) > 4 else 0), os.cpu_count() or 1
        except (OSError, ValueError, IndexError):
            return None

    def idle(self) -> float:
        """Cores idle on average since then (the machine's count where nothing can be read)."""
        end = self._read()
        if self._start is None or end is None or end[0] <= self._start[0]:
            return float(os.cpu_count() or 1)
        return (end[1] - self._start[1]) / (end[0] - self._start[0]) * end[2]


class Background:
    """Forked writers: ``first()`` at once, then ``imports``, then each :meth:`submit`-ted job of a lane in order.

    With ``lanes=2`` the child forks a second one once it has run ``first`` and
    loaded ``imports``: that one starts with the same state and modules (no
    second import), and runs the jobs of lane 1 beside those of lane 0.

    Parameters
    ----------
    first : callable, optional
        Run in the child on the state it inherited (a closure is fine: it is not pickled).
    imports : sequence of module names
        Imported by the child after ``first``, so that later jobs find them loaded.
    lanes : int
        Child processes that run jobs side by side.
    inline : bool
        Run everything in this process instead (no fork).
    """

    def __init__(self, first: Callable[[], object] | None = None, imports: Sequence[str] = (), lanes: int = 1,
                 inline: bool = False):
        self.pid = None
        if inline or not hasattr(os, "fork"):
            if first is not None:
                first()
            return
        sys.stdout.flush()
        sys.stderr.flush()
        jobs = [os.pipe() for _ in range(lanes)]  # (read, write): the parent writes, lane i reads
        done = [os.pipe() for _ in range(lanes)]  # lane i writes its error, the parent reads
        pid = _fork()
        if pid == 0:  # the child: never returns into the caller's code
            code = 1
            try:
                for fd in _PARENT_FDS | {w for _, w in jobs} | {r for r, _ in done}:
                    os.close(fd)
                _PARENT_FDS.clear()
                code = _child(first, imports, [r for r, _ in jobs], [w for _, w in done])
            except BaseException:  # noqa: BLE001 (reported through the pipe where it can be)
                pass
            finally:
                os._exit(code)
        for r, w in jobs:
            os.close(r)
        for r, w in done:
            os.close(w)
        self.pid, self._jobs, self._done = pid, [w for _, w in jobs], [r for r, _ in done]
        _PARENT_FDS.update(self._jobs + self._done)

    @property
    def forked(self) -> bool:
        """Whether the jobs run in a child process (until :meth:`join`)."""
        return self.pid is not None

    def submit(self, fn: Callable, *args, lane: int = 0) -> None:
        """Run ``fn(*args)`` in lane ``lane`` after its jobs before (``fn`` a module-level function; args pickled)."""
        if self.pid is None:
            fn(*args)
        elif self._jobs[lane] is not None:
            try:
                _send(self._jobs[lane], (fn, args))
            except BrokenPipeError:  # the lane stopped at an error: join() raises it
                self._close(self._jobs, lane)

    def join(self) -> None:
        """Wait for every job; raise the first error of a lane, if any."""
        if self.pid is None:
            return
        for lane in range(len(self._jobs)):
            self._close(self._jobs, lane)
        errors = []
        try:
            for lane, fd in enumerate(self._done):
                errors.append(_receive(fd))
                self._close(self._done, lane)
        finally:
            for lane in range(len(self._done)):
                self._close(self._done, lane)
            _, status = os.waitpid(self.pid, 0)
            self.pid = None
        for error in errors:
            if error is not None:
                exc, text = error
                if hasattr(exc, "add_note"):
                    exc.add_note("in the background writer:\n" + text)
                raise exc
        if not os.WIFEXITED(status) or os.WEXITSTATUS(status) != 0:
            raise RuntimeError(f"the background writer ended abnormally (wait status {status})")

    @staticmethod
    def _close(fds: list, lane: int) -> None:
        if fds[lane] is not None:
            os.close(fds[lane])
            _PARENT_FDS.discard(fds[lane])
            fds[lane] = None


def _fork() -> int:
    """``os.fork()``, the child ignoring SIGINT and SIGTERM (its parent decides when the work ends)."""
    stops = {signal.SIGINT, signal.SIGTERM}
    signal.pthread_sigmask(signal.SIG_BLOCK, stops)  # none lands in the child before it ignores them
    pid = -1
    try:
        pid = os.fork()
        if pid == 0:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, stops)  # in the parent: one that came meanwhile is handled now
    return pid


def _run_jobs(jobs_r: int, done_w: int) -> int:
    """Run the jobs read from ``jobs_r`` until it closes; the first error goes to ``done_w`` (then exit code 1)."""
    try:
        while (job := _receive(jobs_r)) is not None:
            fn, args = job
            fn(*args)
    except BaseException as exc:  # noqa: BLE001
        _report(done_w, exc)
        return 1
    return 0


def _report(done_w: int, exc: BaseException) -> None:
    text = traceback.format_exc()
    try:
        _send(done_w, (exc, text))
    except Exception:  # noqa: BLE001 (an exception that does not pickle)
        _send(done_w, (RuntimeError(f"{type(exc).__name__}: {exc}"), text))


def _child(first, imports, jobs_r: list, done_w: list) -> int:
    """Lane 0: ``first``, the imports, then the other lanes forked, then its own jobs; waits for the other lanes."""
    import importlib

    try:
        if first is not None:
            first()
        for name in imports:
            importlib.import_module(name)
    except BaseException as exc:  # noqa: BLE001 (the other lanes never start: their pipes close with this process)
        _report(done_w[0], exc)
        return 1
    others = []
    for lane in range(1, len(jobs_r)):
        pid = _fork()
        if pid == 0:
            code = 1
            try:
                for i in range(len(jobs_r)):
                    if i != lane:
                        os.close(jobs_r[i])
                        os.close(done_w[i])
                code = _run_jobs(jobs_r[lane], done_w[lane])
            finally:
                os._exit(code)
        os.close(jobs_r[lane])
        os.close(done_w[lane])
        others.append(pid)
    code = _run_jobs(jobs_r[0], done_w[0])
    for pid in others:
        _, status = os.waitpid(pid, 0)
        if not os.WIFEXITED(status) or os.WEXITSTATUS(status) != 0:
            code = code or 1
    return code
