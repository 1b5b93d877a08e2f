"""Tasks: what the swarm is asked to do (``swarm.core.tasks.registry``; docs/tasks.md).

Importing this package registers the built-in tasks, in this order: ``rendezvous``, ``formation``,
``coverage``.
"""

from swarm.core.tasks import rendezvous  # noqa: F401  (registers it first: the default task)

# isort: split
from swarm.core.tasks import formation  # noqa: F401

# isort: split
from swarm.core.tasks import coverage  # noqa: F401
from swarm.core.tasks.registry import Task, default_section, get, names, parse_section, register, sections

__all__ = ["Task", "default_section", "get", "names", "parse_section", "register", "sections"]
