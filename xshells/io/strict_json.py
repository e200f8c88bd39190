"""JSON input files read strictly: a key given twice in one object is an error, not "the last one wins".

``json`` keeps the last of repeated keys without a word, so a case file with ``"steps": 3`` and later
``"steps": 4`` ran with 4, whatever its author meant. Every user-written JSON file (case files, sweep
files, cross-section files) is read through :func:`loads`.
"""
from __future__ import annotations

import json

from ..errors import InputError


class _Repeated(ValueError):
    def __init__(self, key: str):
        super().__init__(key)
        self.key = key


def _no_repeats(pairs: list) -> dict:
    out = {}
    for key, value in pairs:
        if key in out:
            raise _Repeated(key)
        out[key] = value
    return out


def loads(text: str, where: str):
    """Parse ``text`` as JSON; one-line :class:`InputError` naming ``where`` for invalid JSON or a repeated key.

    Parameters
    ----------
    text : str
    where : str
        The file (or upload) name, for messages.
    """
    try:
        return json.loads(text, object_pairs_hook=_no_repeats)
    except _Repeated as exc:
        raise InputError(f"{where}: key {exc.key!r} is given twice in one object (JSON keeps only the last): "
                         "give it once") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{where}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    except RecursionError:  # [[[[…]]]] deeper than the parser's stack
        raise InputError(f"{where}: not valid JSON (nested too deeply)") from None
    except ValueError as exc:  # an integer of more than 4300 digits (Python's limit on converting one)
        raise InputError(f"{where}: not valid JSON ({str(exc).split(';')[0]})") from None
