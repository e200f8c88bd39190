"""Running a sweep: serially in-process, on a local Dask cluster, or on an existing scheduler.

Layout of the output folder::

    DIR/sweep.json          the expanded tasks (id -> parameters)
    DIR/results.csv         one row per finished task, rewritten atomically after each
    DIR/tasks/<id>/         the task's own files (deployed.png, result.json, ...)
    DIR/tasks/<id>/task.json  written last: its presence marks the task finished

Only the client writes ``task.json`` and ``results.csv``; workers write their
task folder (``ship_files=False``, the folder must be on a shared file
system) or send the folder back as bytes (``ship_files=True``, design files
are then shipped to the workers too, so nothing needs to be shared).
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import sys
import tempfile
import time
import uuid
from dataclasses import dataclass
from typing import Callable

from ..errors import STOP, InputError
from ..io.export import atomic_write_text
from .order import DispatchOrder
from .spec import PATH_KEYS, SweepSpec, Task
from .tasks import get_task

FINISHED = ("ok", "diverged", "failed")
CSV_INTERVAL_S = 1.0


@dataclass(frozen=True)
class SweepSettings:
    """How a sweep runs.

    Attributes
    ----------
    workers : int or None
        Worker processes of the local cluster (None: one per core; 0: run
        serially in this process). Ignored with ``scheduler``.
    scheduler : str or None
        Address of a running Dask scheduler (``tcp://host:8786``), or
        ``"serial"`` for in-process execution.
    ship_files : bool
        Send input files to workers and outputs back as bytes (no shared file system needed).
    retry_failed : bool
        Re-run tasks recorded as failed or diverged (finished ``ok`` tasks are always kept).
    max_tasks : int or None
        Run at most this many tasks now (the rest on a later run).
    """

    workers: int | None = None
    scheduler: str | None = None
    ship_files: bool = False
    retry_failed: bool = False
    max_tasks: int | None = None

    @property
    def serial(self) -> bool:
        return self.scheduler == "serial" or (self.scheduler is None and self.workers == 0)


@dataclass(frozen=True)
class Progress:
    """What a progress callback receives after each finished task."""

    done: int          # finished in this run
    total: int         # to run in this run
    skipped: int       # already finished before this run
    failed: int        # failed or diverged in this run
    elapsed_s: float
    eta_s: float       # remaining time, extrapolated from the tasks finished so far
    record: dict       # the task.json content of the task just finished


@dataclass(frozen=True)
class SweepReport:
    records: tuple     # task.json contents in sweep order (finished tasks only)
    ran: int
    skipped: int
    failed: int
    wall_s: float
    stopped: bool


def task_dir(out_dir: str, task: Task) -> str:
    return os.path.join(out_dir, "tasks", task.id)


def read_record(out_dir: str, task: Task) -> dict | None:
    """The finished record of ``task`` in ``out_dir``, or None."""
    try:
        with open(os.path.join(task_dir(out_dir, task), "task.json"), encoding="utf-8") as fh:
            rec = json.load(fh)
    except (OSError, json.JSONDecodeError):
        return None
    return rec if rec.get("status") in FINISHED and rec.get("id") == task.id else None


def pending(spec: SweepSpec, records: dict, settings: SweepSettings) -> list:
    """The tasks a run will execute, given the finished ``records`` (id -> record or None)."""
    todo = [t for t in spec.tasks if records.get(t.id) is None
            or (settings.retry_failed and records[t.id]["status"] != "ok")]
    return todo if settings.max_tasks is None else todo[: max(settings.max_tasks, 0)]


def run_sweep(spec: SweepSpec, out_dir: str, settings: SweepSettings = SweepSettings(), *,
              progress: Callable[[Progress], bool | None] | None = None) -> SweepReport:
    """Run the unfinished tasks of ``spec``, streaming results into ``out_dir``.

    Parameters
    ----------
    progress : callable, optional
        Called with a :class:`Progress` after each task; returning True stops
        the sweep (tasks not finished are cancelled; a re-run resumes).

    Returns
    -------
    SweepReport
    """
    from .summary import write_results_csv

    taskdef = get_task(spec.task)  # raises "not available yet" before anything runs
    out_dir = os.path.abspath(out_dir)  # workers elsewhere (or in another folder) get a path that still means it
    _check_same_sweep(spec, out_dir)
    os.makedirs(os.path.join(out_dir, "tasks"), exist_ok=True)
    _write_manifest(spec, out_dir)
    records = {t.id: read_record(out_dir, t) for t in spec.tasks}
    todo = pending(spec, records, settings)
    skipped = sum(r is not None for r in records.values()) - sum(records[t.id] is not None for t in todo)
    write_results_csv(out_dir, spec, records)
    t0 = time.perf_counter()
    done = failed = 0
    stopped = False
    last_csv = [t0]

    def finish(task: Task, rec: dict) -> bool:
        nonlocal done, failed
        outputs = rec.pop("_outputs", None)
        folder = task_dir(out_dir, task)
        os.makedirs(folder, exist_ok=True)
        if outputs:
            _unpack(outputs, folder)
        atomic_write_text(os.path.join(folder, "task.json"), json.dumps(rec, indent=1, default=_json_default))
        records[task.id] = rec
        done += 1
        # at most once a second (and once at the end): a rewrite is O(tasks), every time would be O(tasks²)
        if time.perf_counter() - last_csv[0] > CSV_INTERVAL_S:
            write_results_csv(out_dir, spec, records)
            last_csv[0] = time.perf_counter()
        failed += rec["status"] != "ok"
        if progress is None:
            return False
        elapsed = time.perf_counter() - t0
        eta = elapsed / done * (len(todo) - done)
        return bool(progress(Progress(done, len(todo), skipped, failed, elapsed, eta, rec)))

    try:
        if todo:
            fn = taskdef.fn  # ship the function (or its "module:attr"), not the checks
            if settings.serial:
                for task in todo:
                    files = {p: _read_bytes(p) for p in _paths(task.params)} if settings.ship_files else None
                    if finish(task, execute_task(spec.task, fn, task.id, task.params, task_dir(out_dir, task), files)):
                        stopped = True
                        break
            else:
                stopped = _run_dask(spec, out_dir, settings, fn, todo, finish, taskdef.preload)
    finally:  # stopped, interrupted or crashed: the table matches the task.json markers
        write_results_csv(out_dir, spec, records)
    ordered = tuple(records[t.id] for t in spec.tasks if records[t.id] is not None)
    return SweepReport(ordered, done, skipped, failed, time.perf_counter() - t0, stopped)


def _run_dask(spec, out_dir, settings, fn, todo, finish, preload=()) -> bool:
    """Run the tasks on Dask, one per worker slot at a time, recording them as they complete; True when stopped early."""
    import logging
    import warnings

    forkserver = False
    if not settings.scheduler:
        env = worker_env()
        # numeric libraries on one thread (set before the fork server imports NumPy); the fork server
        # imports Dask and the solvers while this process imports Dask and starts the scheduler
        with _environ(env):
            forkserver = _start_forkserver(["distributed", "xshells.sweeps.run", _module_of(fn), *preload])

    import dask
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if settings.scheduler:
        try:
            client = Client(settings.scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"--scheduler {settings.scheduler}: cannot connect ({_one_line(exc)})") from None
    else:
        n = local_workers(settings.workers, len(todo))[0]
        # no statistical profiler (it samples the task thread's stack every 10 ms, taking the GIL from the
        # solver: it doubled the worker's own CPU time, to about 4% of a core beside the task); glibc's
        # malloc as in a serial run (WORKER_CONFIG)
        config = dict(WORKER_CONFIG, **({"distributed.worker.multiprocessing-method": "forkserver"} if forkserver else {}))
        with warnings.catch_warnings(), _environ(env), dask.config.set(config):
            warnings.simplefilter("ignore", UserWarning)  # "port 8787 in use" when another cluster runs here
            # processes, one thread each: the solvers hold the GIL and JAX/BLAS threads would oversubscribe
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR, env=env)
        client = Client(cluster)
    stopped = False
    try:
        ship = {}
        if settings.ship_files:
            paths = sorted({p for t in todo for p in _paths(t.params)})
            # scattered once, each worker fetches a file once however many tasks use it
            ship = {p: client.scatter(_read_bytes(p), hash=True) for p in paths}
        run_id = uuid.uuid4().hex[:8]  # keys unique per run: several sweeps may share one scheduler
        designs = {}
        order = DispatchOrder(todo, {task.id: estimated_size(task.params, designs) for task in todo})
        running = {}
        ac = as_completed()

        def submit_next() -> None:
            task = order.next()
            files = {p: ship[p] for p in _paths(task.params)} if ship else None
            f = client.submit(execute_task, spec.task, fn, task.id, task.params, task_dir(out_dir, task), files,
                              key=f"xshells-sweep-{task.id}-{run_id}", pure=False)
            running[f.key] = (f, task)
            ac.add(f)

        # one task per worker thread at a time, the next chosen when one finishes (DispatchOrder: dearest
        # first, costs learnt as tasks finish): submitted all at once, the order would be fixed before
        # anything is known of what the tasks cost
        for _ in range(min(_worker_threads(client), len(order))):
            submit_next()
        for f in ac:
            task = running.pop(f.key)[1]
            try:
                rec = f.result()
            except Exception as exc:  # the worker died (KilledWorker, out of memory, ...)
                rec = _record(spec.task, task.id, task.params, "failed", _one_line(exc), {}, 0.0, time.time())
            f.release()  # the cluster may drop the result (and shipped outputs) now
            order.finished(task, rec.get("elapsed_s"))
            # the next task first: the freed worker need not wait for this task's files and table
            for _ in range(min(_worker_threads(client) - len(running), len(order))):
                submit_next()
            if finish(task, rec):
                stopped = True
                client.cancel([g for g, _ in running.values() if not g.done()])
                break
    finally:
        # a second Ctrl-C waits for the cluster to close (seconds): cut short, the close hung for ten
        # seconds more and left worker processes behind
        with STOP.deferred():
            client.close()
            if cluster is not None:
                cluster.close()
    return stopped


def _worker_threads(client) -> int:
    """Task slots of the cluster now (workers may join or leave a shared cluster during the sweep)."""
    try:
        return max(sum(client.nthreads().values()), 1)
    except Exception:  # a scheduler that cannot answer now: keep one task in flight
        return 1


def estimated_size(params: dict, cache: dict | None = None) -> float:
    """A task's size for ordering the dispatch: rod edges × angle steps × the angle (0 if unknown).

    The angle (the target in degrees, or the opening ``open_by_deg``; 1 when
    the task has none) ranks the tasks of one design: a deployment to a wider
    angle takes more Newton iterations per step (the bundled sweep's 75° tasks
    cost 1.15 times its 60° ones). The cost of a task also depends on whether
    and how often its design buckles, which is not known before it runs; the
    size still separates the designs of a sweep over layouts (4k to 40k DoF
    in the paper's zoo).
    """
    import math

    cache = {} if cache is None else cache
    path = params.get("file")
    if not isinstance(path, str):
        return 0
    if path not in cache:
        try:
            from ..io import read_design

            with design_reading(params):
                cache[path] = read_design(path).num_segments
        except Exception:  # a task's own checks report a bad file; the order does not matter then
            cache[path] = 0
    angle = 1.0
    for key, scale in (("angle_deg", 1.0), ("angle_rad", 180.0 / math.pi), ("open_by_deg", 1.0)):
        value = params.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0:
            angle = float(value) * scale
            break
    return cache[path] * int(params.get("subdivision", 10)) * int(params.get("steps", 40)) * angle


def local_workers(requested: int | None, tasks: int) -> tuple[int, str]:
    """The worker processes of a local cluster for ``tasks`` tasks, and a line saying why when fewer than asked.

    ``requested`` (None: one per core), but at most one per task and one per core: more would only wait
    (``--workers 1000`` for one task started 1000 processes on 2 cores and hung).
    """
    cores = _cores()
    n = max(1, min(cores if requested is None else requested, tasks, cores))
    if requested is None or n >= requested:
        return n, ""
    why = f"{tasks} task{'s' * (tasks != 1)} to run" if tasks < cores else f"{cores} core{'s' * (cores != 1)} here"
    return n, f"--workers {requested}: {n} local worker{'s' * (n != 1)} ({why})"


def _cores() -> int:
    """Cores this process may use (a container or batch job may allow fewer than the machine has)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


# One thread per local worker for every numeric library: a worker per core, each running one task, and
# OpenBLAS's or XLA's own pools (a thread per core each) would put several busy threads on every core.
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
XLA_ONE_THREAD = "--xla_cpu_multi_thread_eigen=false"
WORKER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    # Dask's nanny sets MALLOC_TRIM_THRESHOLD_=65536 in workers; setting it at all turns off glibc's
    # adaptive mmap threshold, so every NumPy temporary above 128 KiB is mapped and zeroed anew: 35x
    # the page faults and 1.5x the CPU time of a deploy task (sys time 0.3 -> 4.4 s). Leave it unset.
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    # a worker runs one task of seconds at a time: its event loop need not wake every 20 ms to time
    # itself, nor poll its memory every 100 ms (each wake-up takes the GIL from the solver)
    "distributed.admin.tick.interval": "500ms",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
}


def worker_env(environ=None) -> dict:
    """Environment variables that pin a worker's numeric libraries to one thread.

    BLAS reads its variable when NumPy is imported, XLA when JAX first runs,
    so they must be set before either: :func:`_run_dask` sets them while the
    fork server (which imports NumPy) and the workers start. An ``XLA_FLAGS``
    already set is kept, with the single-thread flag added.
    """
    environ = os.environ if environ is None else environ
    env = {k: "1" for k in THREAD_VARS}
    xla = environ.get("XLA_FLAGS", "")
    env["XLA_FLAGS"] = xla if "xla_cpu_multi_thread_eigen" in xla else f"{xla} {XLA_ONE_THREAD}".strip()
    return env


@contextlib.contextmanager
def _environ(env: dict):
    """Set ``env`` in this process while local workers start (their fork server inherits it), then restore."""
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _module_of(fn) -> str:
    return fn.partition(":")[0] if isinstance(fn, str) else getattr(fn, "__module__", "xshells")


def _start_forkserver(modules: list) -> bool:
    """Start the fork server that local workers are forked from, importing ``modules`` once; False if none.

    Spawned workers would each import Dask and the solvers (about 1.5 s
    apiece, all at once); forking from a server that imported them (but
    never ran JAX, so no threads exist yet) shares that cost. The server is
    started here, before this process imports Dask itself, so that the two
    imports overlap (0.7 s for Dask alone). A server already running (an
    earlier sweep in this process) is reused as it is.
    """
    import multiprocessing

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return False
    from multiprocessing import forkserver

    multiprocessing.get_context("forkserver").set_forkserver_preload([m for m in modules if m])
    with _children_ignore_ctrl_c():
        forkserver.ensure_running()
    return True


@contextlib.contextmanager
def _children_ignore_ctrl_c():
    """Processes started meanwhile ignore Ctrl-C, and one meant for this process is not lost.

    The terminal sends Ctrl-C to every process of the command: each local worker printed its
    traceback (asyncio's CancelledError, then KeyboardInterrupt) while the sweep was still stopping.
    An ignored signal stays ignored through exec (and Python then leaves it so), and the fork server
    hands its workers the handler it started with: they all ignore it, and this process alone stops,
    keeps the finished tasks and closes the cluster, which ends the workers. SIGINT is blocked
    meanwhile, so that one that comes is delivered here afterwards (Linux keeps a blocked signal
    pending even while it is ignored).
    """
    import signal
    import threading

    handler = signal.getsignal(signal.SIGINT)
    if (not hasattr(signal, "pthread_sigmask") or handler is None  # Windows; a handler set outside Python
            or threading.current_thread() is not threading.main_thread()):  # only the main thread may set one
        yield
        return
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def execute_task(task_name: str, fn, task_id: str, params: dict, out_dir: str, files: dict | None) -> dict:
    """Run one task where it lands (a worker or this process); never raises for a task's own failure.

    With ``files`` (path -> bytes) the inputs are written to a scratch folder,
    the task runs there and its outputs come back under ``_outputs``.
    """
    from .tasks import TaskDef

    started = time.time()
    t0, c0 = time.perf_counter(), time.process_time()
    scratch = None
    given = params  # recorded as given, not as relocated into the scratch folder
    try:
        if files is not None:
            scratch = tempfile.mkdtemp(prefix="xshells-sweep-")
            params = _relocate(params, files, scratch)
            out_dir = os.path.join(scratch, "out")
        os.makedirs(out_dir, exist_ok=True)
        try:
            with design_reading(params):
                result = TaskDef(task_name, fn)(params, out_dir)
            status = "ok" if result.get("converged", True) else "diverged"
            error = "" if status == "ok" else str(result.get("message", "did not converge"))
        except Exception as exc:  # a task's failure is data, the sweep goes on
            result, status, error = {}, "failed", _one_line(exc)
        rec = _record(task_name, task_id, given, status, error, result, time.perf_counter() - t0, started,
                      time.process_time() - c0)
        if scratch is not None:
            rec["_outputs"] = _pack(out_dir)
        return rec
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)


@contextlib.contextmanager
def design_reading(params: dict):
    """Read ``.3dm`` designs with the task's ``layer`` and ``sample`` (:data:`xshells.sweeps.spec.DESIGN_OPTIONS`)
    meanwhile: the reader's options are process-wide, and a worker process never saw the command line's."""
    from ..rhino.read import get_defaults, set_defaults

    saved = get_defaults()
    set_defaults(layer=params.get("layer"), sample=params.get("sample"), target_layer=saved["target_layer"])
    try:
        yield
    finally:
        set_defaults(**saved)


def _record(task_name, task_id, params, status, error, result, elapsed, started, cpu=None) -> dict:
    import resource

    scalars = {k: v for k, v in result.items() if isinstance(v, (bool, int, float, str)) or v is None}
    return {
        "id": task_id,
        "task": task_name,
        "status": status,
        "error": error,
        "result": scalars,
        "params": params,
        "started": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(started)),
        "elapsed_s": elapsed,
        "cpu_s": cpu,  # well below elapsed_s: the task waited for a core (a busy machine)
        # peak resident memory of the process that ran it (KiB on Linux): what a worker needs per task
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / (1024 if sys.platform != "darwin" else 1024**2),
        "host": socket.gethostname(),
        "pid": os.getpid(),
    }


def _one_line(exc: BaseException) -> str:
    msg = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__


def _json_default(v):
    if hasattr(v, "item"):  # numpy scalars
        return v.item()
    if hasattr(v, "tolist"):
        return v.tolist()
    return str(v)


def _paths(params: dict) -> list:
    out = []
    for key in PATH_KEYS:
        head, _, tail = key.partition(".")
        v = params.get(head, {}).get(tail) if tail else params.get(head)
        if v:
            out.append(v)
    return out


def _relocate(params: dict, files: dict, scratch: str) -> dict:
    """Write shipped inputs under ``scratch`` and point ``params`` at them."""
    import copy

    params = copy.deepcopy(params)
    local = {}
    for i, (path, data) in enumerate(sorted(files.items())):
        local[path] = os.path.join(scratch, "in", f"{i}_{os.path.basename(path)}")
        os.makedirs(os.path.dirname(local[path]), exist_ok=True)
        with open(local[path], "wb") as fh:
            fh.write(data)
    for key in PATH_KEYS:
        head, _, tail = key.partition(".")
        holder, k = (params.get(head), tail) if tail else (params, head)
        if isinstance(holder, dict) and holder.get(k) in local:
            holder[k] = local[holder[k]]
    return params


def _read_bytes(path: str) -> bytes:
    with open(path, "rb") as fh:
        return fh.read()


def _pack(folder: str) -> dict:
    out = {}
    for root, _, names in os.walk(folder):
        for n in names:
            p = os.path.join(root, n)
            out[os.path.relpath(p, folder)] = _read_bytes(p)
    return out


def _unpack(files: dict, folder: str) -> None:
    for rel, data in files.items():
        path = os.path.join(folder, rel)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tmp = path + ".tmp"
        with open(tmp, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)


def _check_same_sweep(spec: SweepSpec, out_dir: str) -> None:
    """Refuse an output folder that holds another sweep (another name or task): its manifest would be replaced
    and its tasks' folders mixed with these. The same sweep, edited (more values), resumes there."""
    path = os.path.join(out_dir, "sweep.json")
    if not os.path.exists(path):
        return
    try:
        with open(path, encoding="utf-8") as fh:
            old = json.load(fh)
    except (OSError, ValueError):
        raise InputError(f"--out {out_dir}: its sweep.json cannot be read: give another --out, or remove it") from None
    if not isinstance(old, dict) or (old.get("name"), old.get("task")) != (spec.name, spec.task):
        held = f"the sweep {old.get('name')!r} (task {old.get('task')})" if isinstance(old, dict) else "another sweep"
        raise InputError(f"--out {out_dir} holds {held}, not {spec.name!r} (task {spec.task}): give another --out, "
                         "or remove that folder")


def _write_manifest(spec: SweepSpec, out_dir: str) -> None:
    manifest = {"name": spec.name, "task": spec.task, "base_dir": spec.base_dir, "varying": list(spec.varying_keys),
                "tasks": [{"id": t.id, "index": t.index, "varying": t.varying, "params": t.params} for t in spec.tasks]}
    atomic_write_text(os.path.join(out_dir, "sweep.json"), json.dumps(manifest, indent=1, default=_json_default))
