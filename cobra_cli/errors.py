"""Errors a user can fix; the CLI prints them as one line and exits with status 2."""
from __future__ import annotations

from cobra_model.errors import InputError

#: Exception types the CLI reports as one line, without a traceback.
USER_ERRORS: tuple[type[BaseException], ...] = (
    InputError,
    FileNotFoundError,
    FileExistsError,
    IsADirectoryError,
    PermissionError,
)
