"""The ``xshells`` command line.

Each subcommand lives beside the code it drives, in a module that exposes
``register(subparsers)``; this file only collects them. A subcommand's
handler returns an exit code. Errors that the user can fix are raised as
:class:`xshells.errors.InputError` and printed as one line, never as a
traceback (exit 2). Anything else is a bug of ours: one line too, exit 3, the
traceback written to ``OUT/error.log``; ``--debug`` (anywhere on the command
line) shows it instead. An output folder that cannot be created or written is
refused before any work starts.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

from .errors import InputError

# One BLAS thread unless the user says otherwise (set before NumPy loads its BLAS): the solver's
# dense kernels are small, and two OpenBLAS threads made the manta ray's deploy phase 15-20 %
# slower on 2 cores (2.42 s against 2.02 s at 10 steps, 2026-12-02).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# module path -> imported lazily so that ``xshells --help`` stays fast
SUBCOMMANDS = [
    "xshells.deploy.cli",
    "xshells.section.cli",
    "xshells.actuation.cli",
    "xshells.sweeps.cli",
    "xshells.app.cli",
    "xshells.design.cli",
    "xshells.inverse.cli",
    "xshells.analysis.cli",
    "xshells.fabrication.cli",
    "xshells.rhino.cli",
]


DESIGN_COMMANDS = ("deploy", "optimize", "sparsify", "fabricate", "analyze", "app", "sweep")
# the commands that read a target surface, and the option that names it
SURFACE_COMMANDS = {"optimize": "target_surface", "inverse": "surface"}


class _Parser(argparse.ArgumentParser):
    """argparse, with its errors in one line as every other input error (it printed the whole usage first);
    the subcommands' parsers are of this class too (argparse makes them of their parent's)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        import re

        # a negative number in any notation is a value, not an option: argparse's own pattern misses "-1e-9", and
        # "--density -1e-9" was "expected one argument" instead of the option's own message
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser(modules: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser with the subcommands of ``modules`` (default: all of :data:`SUBCOMMANDS`)."""
    parser = _Parser(
        prog="xshells",
        description="Design, simulate and fabricate X-shells (deployable elastic gridshells).",
    )
    from . import __version__

    parser.add_argument("--version", action="version", version=f"xshells {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS if modules is None else modules:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:  # a subcommand still being built
            if exc.name != name:
                raise
            continue
        mod.register(sub)
    for name, sp in sub.choices.items():  # the commands that read a design file or a surface: their .3dm options
        if name in DESIGN_COMMANDS or name in SURFACE_COMMANDS:
            g = sp.add_argument_group("Rhino .3dm input")
        if name in DESIGN_COMMANDS:
            g.add_argument("--layer", help="the layer of a .3dm design to read (default: its one layer holding curves)")
            g.add_argument("--sample", type=int, metavar="N",
                           help="replace each curved curve of a .3dm design by N straight segments (default: refuse them)")
        if name in SURFACE_COMMANDS:  # a layer of its own: the design's and the surface's differ in one file
            g.add_argument("--target-layer", metavar="LAYER",
                           help="the layer of a .3dm target surface to read (default: its one layer holding meshes "
                                "or surfaces)")
    return parser


def _parser_for(argv: list[str]) -> argparse.ArgumentParser:
    """A parser with only the named subcommand's module when that is ``xshells.<command>.cli``, else all.

    Importing a subcommand's package may load the solver (JAX, SciPy); ``xshells
    app`` must serve its page first, so it does not import the others.
    """
    if argv and f"xshells.{argv[0]}.cli" in SUBCOMMANDS:
        parser = build_parser([f"xshells.{argv[0]}.cli"])
        sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        if sub is not None and argv[0] in sub.choices:
            return parser
    return build_parser()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv  # anywhere on the line: show tracebacks of internal errors
    argv = [a for a in argv if a != "--debug"]
    import signal

    from .errors import STOP

    STOP.reset()

    def _terminate(signum, frame):  # SIGTERM and Ctrl-C: work is kept and files are complete or absent
        # The flag is checked again at the next step, should a finalizer swallow the
        # exception; inside STOP.deferred() (a run's last files) nothing is raised yet.
        STOP.request(frame, signum)

    # Installed before the parser is built: importing a subcommand takes up to a second, and a Ctrl-C
    # then printed Python's traceback of the import.
    previous = {}
    for name in ("SIGTERM", "SIGINT"):
        try:
            previous[name] = signal.signal(getattr(signal, name), _terminate)
        except (ValueError, AttributeError):  # not the main thread, or no such signal here
            pass
    try:
        try:
            parser = _parser_for(argv)
            args = parser.parse_args(argv)
            STOP.check()  # one that came during the imports
        except KeyboardInterrupt:
            command = argv[0] if argv and not argv[0].startswith("-") else None
            word, code = STOP.how()
            print(f"xshells{f' {command}' if command else ''}: {word}", file=sys.stderr)
            return code
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        return _run(args, debug)
    finally:
        STOP.cancel_pending()
        for name, handler in previous.items():
            signal.signal(getattr(signal, name), handler)


def _execute(args) -> int:
    """Runs a parsed command; input errors propagate as :class:`InputError`."""
    out = getattr(args, "out", None)
    fresh = None  # the output folder, if this run is the one that creates it
    if isinstance(out, str):  # refused before any work starts (an empty one too: a default is None)
        from .io.export import prepare_output_dir

        fresh = None if os.path.exists(out) else out
        prepare_output_dir(out)
    try:
        return _execute_checked(args)
    except InputError:
        # refused after the command made its folder (a check that needs the design): leave nothing behind
        if fresh is not None and os.path.isdir(fresh) and not os.listdir(fresh):
            os.rmdir(fresh)
        raise


def _execute_checked(args) -> int:
    # Floating-point warnings (overflow, 0/0 in a collapsing state) are not for the
    # command line: a run that goes wrong says so in its own one-line message.
    import numpy as np

    if hasattr(args, "layer") or hasattr(args, "target_layer"):  # this command's .3dm options (None: the reader's own)
        from .rhino.read import set_defaults

        given = [f"--{k}" for k in ("layer", "sample") if getattr(args, k, None) is not None]
        path = next((v for v in (getattr(args, k, None) for k in ("input", "case", "design")) if isinstance(v, str)), "")
        if given and path.lower().endswith((".obj", ".msh")):  # they would be ignored
            raise InputError(f"{' and '.join(given)} read{'s' * (len(given) == 1)} a .3dm design: {path} is not one")
        target_layer = getattr(args, "target_layer", None)
        if target_layer is not None:
            surface = getattr(args, SURFACE_COMMANDS.get(args.command, ""), None)
            if not isinstance(surface, str) or not surface.lower().endswith(".3dm"):
                raise InputError("--target-layer reads a .3dm target surface: "
                                 + (f"{surface} is not one" if isinstance(surface, str) else "none is given"))
        set_defaults(layer=getattr(args, "layer", None), sample=getattr(args, "sample", None), target_layer=target_layer)
    with np.errstate(all="ignore"):
        return int(args.func(args) or 0)


def run_in_process(argv: list[str]) -> int:
    """Runs ``xshells ARGV`` in this process, as the command line would, and returns its exit code.

    For callers that report errors their own way (the Hops server): an input
    error, or an option the parser refuses, raises :class:`InputError` with
    its one line instead of printing it.
    """
    import contextlib
    import io

    parser = _parser_for(list(argv))
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            args = parser.parse_args(list(argv))
    except SystemExit:
        lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
        raise InputError(lines[-1] if lines else f"invalid options: {' '.join(argv)}") from None
    return _execute(args)


def _run(args, debug: bool) -> int:
    try:
        return _execute(args)
    except InputError as exc:
        print(f"xshells {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        from .errors import STOP

        word, code = STOP.how()  # SIGTERM: "terminated", 143; Ctrl-C: "interrupted", 130
        kept = getattr(exc, "kept", "")  # where a command says what it kept (xshells deploy: its finished steps)
        print(f"xshells {args.command}: {word}{f'; {kept}' if kept else ''}", file=sys.stderr)
        return code
    except Exception as exc:  # a bug of ours, not the user's input: one line, the traceback kept
        if debug:
            raise
        return _internal_error(args, exc)


def _internal_error(args, exc: Exception) -> int:
    import traceback

    text = "".join(traceback.format_exception(exc))
    where = ""
    out = getattr(args, "out", None)
    if isinstance(out, str) and out:
        try:
            from .io.export import atomic_write_text

            os.makedirs(out, exist_ok=True)
            atomic_write_text(os.path.join(out, "error.log"), text)
            where = f"; the traceback is in {os.path.join(out, 'error.log')}"
        except OSError:
            pass
    msg = " ".join(str(exc).split())[:300] or "no message"
    print(f"xshells {args.command}: internal error ({type(exc).__name__}: {msg}); run with --debug for the "
          f"traceback{where}", file=sys.stderr)
    return 3


def entry() -> None:
    """The ``xshells`` command: :func:`main`, then the process ends without tearing the interpreter down.

    Every file is written and closed by then; what is left is freeing modules and arrays, which the
    operating system does at once: 0.08 of a second after ``xshells deploy`` returned on the manta ray,
    against 0.02 this way. Exit handlers still run. Where another thread is alive (a server's), the
    ordinary exit waits for it as before; under a profiler or tracer (``python -m cProfile -m
    xshells.cli``, coverage) too, as they write their results after the program returns.
    """
    try:
        code = main()
    except KeyboardInterrupt:  # before main installed its handler (the first hundredths of a second)
        print("xshells: interrupted", file=sys.stderr)
        code = 130
    import atexit
    import threading

    run_exit_handlers = getattr(atexit, "_run_exitfuncs", None)
    if threading.active_count() > 1 or run_exit_handlers is None or sys.getprofile() or sys.gettrace():
        sys.exit(code)
    run_exit_handlers()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (xshells ... | head): nothing more to say
            pass
    os._exit(code)


if __name__ == "__main__":
    entry()
