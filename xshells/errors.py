"""Errors that describe bad input in one line."""
import contextlib
import sys


class InputError(ValueError):
    """Bad user input: the message names the file, line or element and what is wrong."""


class InvalidState(InputError):
    """Variables the model cannot take (a non-positive rest length, a non-finite coordinate).

    From a user it is bad input; inside a solver it marks a trial point outside
    the domain, which a line search answers by shortening its step.
    """


_SPECIAL_FILES = (("S_ISDIR", "a folder"), ("S_ISFIFO", "a named pipe"), ("S_ISCHR", "a device"),
                  ("S_ISBLK", "a device"), ("S_ISSOCK", "a socket"))


def check_input_file(path, what: str = "file") -> None:
    """Refuse ``path`` in one line if it exists but is not a regular file (a folder, a named pipe, a device).

    Readers call this before they open a file: a named pipe blocks until something writes to it, and
    /dev/zero reads until the memory runs out. A path that does not exist is left to the reader's own
    message.
    """
    import os
    import stat

    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):  # missing, unreadable, a name the system refuses: the reader says which
        return
    if not stat.S_ISREG(mode):
        kind = next((k for test, k in _SPECIAL_FILES if getattr(stat, test)(mode)), "a special file")
        raise InputError(f"{path}: cannot read {what} ({kind}, not a regular file)")


class _StopRequest:
    """Whether the user asked to stop (SIGTERM, or Ctrl-C as the command line sees it).

    The command line's SIGTERM handler raises KeyboardInterrupt in whatever
    Python code runs at that moment; where that is a finalizer (``__del__``),
    Python prints and drops the exception. Long loops therefore also check
    this flag at their own checkpoints (a deployment step), so that a stop
    is never lost.
    """

    def __init__(self):
        self.requested = False
        self.signum = None  # the signal that asked (None: Ctrl-C as a KeyboardInterrupt, or not asked)
        self.deferring = 0  # > 0: inside :meth:`deferred`, the handler only records the request
        self._pending = None  # a signal waiting for an import to end (its cancel event)

    def reset(self) -> None:
        """No stop requested (a command starts)."""
        self.requested = False
        self.signum = None

    @property
    def terminated(self) -> bool:
        """Whether the stop was a SIGTERM (a kill, a scheduler), not Ctrl-C."""
        import signal

        return self.signum is not None and self.signum == getattr(signal, "SIGTERM", None)

    def how(self) -> tuple[str, int]:
        """How a stopped command ends: its word and exit code ("terminated", 143 = 128 + SIGTERM, the
        shells' convention; else "interrupted", 130 = 128 + SIGINT)."""
        return ("terminated", 143) if self.terminated else ("interrupted", 130)

    def check(self) -> None:
        """Raise KeyboardInterrupt if a stop was requested."""
        if self.requested:
            raise KeyboardInterrupt

    def request(self, frame=None, signum=None) -> None:
        """What the command line's signal handler does: record the stop, and raise unless deferred.

        ``frame``, ``signum``: the handler's arguments. A stop that lands while a module is being
        imported is raised once the import has ended: raised inside it, it would leave the module
        half-initialised in ``sys.modules`` (a Ctrl-C while matplotlib loaded made the interrupted
        deploy's last files fail with "module 'matplotlib' has no attribute 'get_data_path'").
        """
        self.requested = True
        if signum is not None and self.signum is None:  # the first one says how the run ended
            self.signum = signum
        if self.deferring:
            return
        if frame is not None and signum is not None and _importing(frame):
            self._redeliver_after_import(signum)
            return
        raise KeyboardInterrupt

    def _redeliver_after_import(self, signum) -> None:
        """Deliver ``signum`` again to the main thread (its handler: :meth:`request`) once its imports are over."""
        if self._pending is not None:  # one is on its way already
            return
        import _thread
        import threading

        main = threading.main_thread().ident
        cancelled = self._pending = threading.Event()

        def watch():
            while _importing(sys._current_frames().get(main)) and not cancelled.wait(0.01):
                pass
            if self._pending is cancelled:
                self._pending = None
            if not cancelled.is_set():
                _thread.interrupt_main(signum)

        threading.Thread(target=watch, daemon=True, name="xshells-stop").start()

    def cancel_pending(self) -> None:
        """Drop a signal still waiting for an import to end (the command is over, its handler is being removed)."""
        if self._pending is not None:
            self._pending.set()
            self._pending = None

    @contextlib.contextmanager
    def deferred(self):
        """A region a stop must not cut short (the last summaries and files of a run).

        A stop that arrives inside it waits: the region runs to its end, and
        :meth:`check` afterwards raises. Keep such regions short (seconds).
        """
        self.deferring += 1
        try:
            yield
        finally:
            self.deferring -= 1


def _importing(frame) -> bool:
    """Whether ``frame`` runs inside an import: importlib's own frames are among its callers."""
    while frame is not None:
        name = frame.f_code.co_filename
        if "importlib._bootstrap" in name or name.endswith(("/_bootstrap.py", "/_bootstrap_external.py")):
            return True
        frame = frame.f_back
    return False


STOP = _StopRequest()
