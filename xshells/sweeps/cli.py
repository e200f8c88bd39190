"""``xshells sweep``: run a design-space sweep on Dask."""
from __future__ import annotations

from ..errors import InputError
from .spec import MAX_TASKS


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sweep", help="run many deploy/optimize/sparsify tasks over a design space (Dask)",
        description="Run every point of a sweep file (YAML or JSON: a base case, axes to vary, a task) on a local "
                    "Dask cluster or an existing scheduler. Results stream into --out; a re-run skips finished tasks.")
    p.add_argument("spec", help="sweep file (.yaml, .yml or .json); see docs/sweeps.md")
    p.add_argument("--out", required=True, help="output folder (results.csv, tasks/<id>/, plots)")
    p.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://host:8786")
    p.add_argument("--workers", type=int, help="local worker processes (default: one per core; at most one per task and core; 0: run serially in this process)")
    p.add_argument("--ship-files", action="store_true", help="send input files to the workers and outputs back (no shared file system)")
    p.add_argument("--retry-failed", action="store_true", help="re-run tasks recorded as failed or diverged")
    p.add_argument("--max-tasks", type=int, help="run at most this many unfinished tasks now")
    p.add_argument("--force", action="store_true",
                   help=f"run a sweep of more than {MAX_TASKS:,} tasks (refused without it: most likely a mistake)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_sweep)


def _sweep(args) -> int:
    from .run import SweepSettings, run_sweep
    from .spec import load_spec
    from .summary import format_table, write_summary

    if args.workers is not None and args.workers < 0:
        raise InputError(f"--workers must be 0 (serial) or more, got {args.workers}")
    if args.max_tasks is not None and args.max_tasks < 1:
        raise InputError(f"--max-tasks must be at least 1, got {args.max_tasks} (leave it out to run every task)")
    if args.workers is not None and args.scheduler:
        raise InputError("--workers sizes a local cluster; it contradicts --scheduler")
    # --layer and --sample (xshells.cli) become task parameters: set only here, the workers would not see them
    options = {k: getattr(args, k, None) for k in ("layer", "sample")}
    spec = load_spec(args.spec, max_tasks=None if args.force else MAX_TASKS, design_options=options)
    settings = SweepSettings(workers=args.workers, scheduler=args.scheduler, ship_files=args.ship_files,
                             retry_failed=args.retry_failed, max_tasks=args.max_tasks)
    from .run import local_workers, pending, read_record

    todo = pending(spec, {t.id: read_record(args.out, t) for t in spec.tasks}, settings)
    if todo and not settings.serial and not settings.scheduler:
        note = local_workers(settings.workers, len(todo))[1]
        if note:
            print(f"note: {note}")
    bar = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc=f"sweep {spec.name}", unit="task")  # tqdm's rate gives the ETA

    def on_progress(info) -> bool:
        if bar is not None:
            bar.set_postfix(failed=info.failed, last=info.record["status"])
            bar.update(1)
        return False

    try:
        report = run_sweep(spec, args.out, settings, progress=on_progress)
    finally:
        if bar is not None:
            bar.close()
    records = {r["id"]: r for r in report.records}
    plots = write_summary(args.out, spec, records)
    print(format_table(spec, records))
    print(f"{spec.name}: {len(spec.tasks)} tasks, {report.ran} run now ({report.failed} failed or diverged), "
          f"{report.skipped} already finished; {report.wall_s:.1f} s")
    print(f"  results in {args.out}/results.csv" + (f"; plots: {', '.join(p.split('/')[-1] for p in plots)}" if plots else ""))
    return 0 if all(r["status"] == "ok" for r in report.records) and len(report.records) == len(spec.tasks) else 1
