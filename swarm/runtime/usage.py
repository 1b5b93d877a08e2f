"""Bad input on any command line of the project gives one line on stderr and exit status 2.

``OneLineArgumentParser`` is ``argparse.ArgumentParser`` whose errors are one line (argparse prints
the whole usage first); :func:`positive_int`, :func:`positive_float`, :func:`probability` and the
others are ``type=`` checks that turn a bad value (``--seeds six``, ``--gain -1``) into such a line;
:func:`one_line` turns any exception into one line for the user;
:func:`silenced_stderr` keeps a C library's chatter (pybullet prints its build time on import) off it;
:func:`configure_logging` is how a command line decides what the user sees of the library's log records.
Standard library only (and ``swarm.core.exit_codes``): robot agents use it.
"""

from __future__ import annotations

import argparse
import logging
import math
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


def _number(text: str, kind: type[int] | type[float]) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected {'an integer' if kind is int else 'a number'}, got {text!r}"
        ) from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1 (``--seeds``, ``--workers``, robot counts)."""
    value = int(_number(text, int))
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def non_negative_int(text: str) -> int:
    """An integer >= 0 (a random seed)."""
    value = int(_number(text, int))
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {text!r}")
    return value


def robot_count(text: str) -> int:
    """A swarm size N >= 2."""
    value = int(_number(text, int))
    if value < 2:
        raise argparse.ArgumentTypeError(f"every N must be at least 2 (a swarm), got {text!r}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0 (durations in s, gains in 1/s, speeds in m/s)."""
    value = _number(text, float)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be greater than 0, got {text!r}")
    return value


def probability(text: str) -> float:
    """A probability in [0, 1) (a message-loss rate: 1 would cut every link)."""
    value = _number(text, float)
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"must be in [0, 1), got {text!r}")
    return value


def limit_spec(text: str) -> tuple[str | None, int, int]:
    """``N:STARTS`` or ``TOPOLOGY:N:STARTS`` -> (topology or None, N, STARTS)."""
    parts = text.split(":")
    if len(parts) not in (2, 3) or (len(parts) == 3 and not parts[0]):
        raise argparse.ArgumentTypeError(f"expected N:STARTS or TOPOLOGY:N:STARTS, got {text!r}")
    try:
        count, starts = robot_count(parts[-2]), positive_int(parts[-1])
    except argparse.ArgumentTypeError as error:
        raise argparse.ArgumentTypeError(f"in {text!r}: {error}") from None
    return (parts[0] if len(parts) == 3 else None), count, starts


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
