"""The project's error for input a user can fix.

Every validation error (a run file, a parameter file, a bus configuration, a CLI option)
is an :class:`InputError` whose message names the file, the column or the parameter and what
was expected. The ``cobra`` CLI prints these as one line without a traceback.
"""
from __future__ import annotations


class InputError(ValueError):
    """Bad input from the user: the message says where and what was expected."""
