"""Bad input on any command line of the project gives one line on stderr and exit status 2.

``OneLineArgumentParser`` is ``argparse.ArgumentParser`` whose errors are one line (argparse prints
the whole usage first); :func:`one_line` turns any exception into one line for the user;
:func:`silenced_stderr` keeps a C library's chatter (pybullet prints its build time on import) off it;
:func:`configure_logging` is how a command line decides what the user sees of the library's log records.
Standard library only (and ``swarm.core.exit_codes``): robot agents use it.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import NoReturn

from swarm.core.exit_codes import ExitCode

EXIT_BAD_INPUT = ExitCode.BAD_INPUT


def one_line(error: BaseException) -> str:
    """The first line of an error's message (Zenoh's errors end in a Rust source location: cut)."""
    text = str(error).strip()
    if not text:
        return type(error).__name__
    text = text.splitlines()[0].split(" at /")[0]
    return text.removeprefix('Json5Err(Message { msg: "').rstrip()


class OneLineArgumentParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line: ``prog: error: ... (see prog --help)``."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: error: {message} (see {self.prog} --help)\n")
        sys.exit(EXIT_BAD_INPUT)


@contextmanager
def silenced_stderr() -> Iterator[None]:
    """File descriptor 2 goes to /dev/null inside the block (what C code prints there too)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


PROJECT_LOGGERS = ("swarm", "sim_server", "robot_agent")


class _ConsoleHandler(logging.Handler):
    """Log records as the command line's own lines: INFO and below on stdout, warnings and errors on
    stderr, each its message alone (the library writes whole lines). The streams are looked up at
    each record, so a redirected ``sys.stdout`` is honoured."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            stream = sys.stdout if record.levelno <= logging.INFO else sys.stderr
            stream.write(self.format(record) + "\n")
            stream.flush()
        except Exception:
            self.handleError(record)


def configure_logging(verbosity: int = 0) -> None:
    """What a command line shows of the project's log records (loggers ``swarm``, ``sim_server``,
    ``robot_agent``): ``verbosity`` -1 (``--quiet``) warnings and errors only, 0 (default) also
    information, 1 or more (``-v``) also debug records. Calling it again replaces the earlier setting
    (commands run in-process, as tests do). Other libraries' loggers are left alone."""
    level = logging.WARNING if verbosity < 0 else logging.INFO if verbosity == 0 else logging.DEBUG
    for name in PROJECT_LOGGERS:
        logger = logging.getLogger(name)
        for handler in [h for h in logger.handlers if isinstance(h, _ConsoleHandler)]:
            logger.removeHandler(handler)
        handler = _ConsoleHandler()
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
        logger.setLevel(level)
