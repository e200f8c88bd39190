"""Errors that describe bad input in one line."""


class InputError(ValueError):
    """Bad user input: the message names the file, line or element and what is wrong."""


class InvalidState(InputError):
    """Variables the model cannot take (a non-positive rest length, a non-finite coordinate).

    From a user it is bad input; inside a solver it marks a trial point outside
    the domain, which a line search answers by shortening its step.
    """
