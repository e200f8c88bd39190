"""Errors that describe bad input in one line."""


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

    def check(self) -> None:
        """Raise KeyboardInterrupt if a stop was requested."""
        if self.requested:
            raise KeyboardInterrupt


STOP = _StopRequest()
