"""The exit statuses of every command line of the project (``swarm``, the sim server, the robot agents).

One definition, in the lowest layer, so that the command line, the runtime, the processes and the
results all read the same numbers.
"""

from __future__ import annotations

from enum import IntEnum


class ExitCode(IntEnum):
    SUCCESS = 0
    """Ran and succeeded (converged, done)."""
    NOT_MET = 1
    """Ran but did not succeed, or did not complete (not converged, a run that failed or was cut short)."""
    BAD_INPUT = 2
    """Bad input only (a file, key or option): one line naming it and why."""
    INTERRUPTED = 130
    """Interrupted (Ctrl-C, SIGTERM)."""
