"""Errors that describe bad input in one line."""
import contextlib


class InputError(ValueError):
    """Bad user input: the message names the file, line or element and what is wrong."""


class InvalidState(InputError):
    """Variables the model cannot take (a non-positive rest length, a non-finite coordinate).

    From a user it is bad input; inside a solver it marks a trial point outside
    the domain, which a line search answers by shortening its step.
    """


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
        self.deferring = 0  # > 0: inside :meth:`deferred`, the handler only records the request

    def check(self) -> None:
        """Raise KeyboardInterrupt if a stop was requested."""
        if self.requested:
            raise KeyboardInterrupt

    def request(self) -> None:
        """What the command line's signal handler does: record the stop, and raise unless deferred."""
        self.requested = True
        if not self.deferring:
            raise KeyboardInterrupt

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


STOP = _StopRequest()
