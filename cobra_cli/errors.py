"""Errors a user can fix; the CLI prints them as one line and exits with status 2."""
from __future__ import annotations

from cobra_model.errors import InputError
from integrators.simulator import SimulationDiverged

#: Exception types the CLI reports as one line, without a traceback. A diverged simulation is
#: reported the same way: its message names the time, the place and the setting to change.
USER_ERRORS: tuple[type[BaseException], ...] = (
    InputError,
    SimulationDiverged,
    FileNotFoundError,
    FileExistsError,
    IsADirectoryError,
    PermissionError,
)
