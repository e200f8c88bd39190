"""Errors that describe bad input in one line."""


class InputError(ValueError):
    """Bad user input: the message names the file, line or element and what is wrong."""
