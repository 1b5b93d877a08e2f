"""Bad input on any command line of the project gives one line on stderr and exit status 2.

``OneLineArgumentParser`` is ``argparse.ArgumentParser`` whose errors are one line (argparse prints
the whole usage first); :func:`one_line` turns any exception into one line for the user;
:func:`silenced_stderr` keeps a C library's chatter (pybullet prints its build time on import) off it.
Standard library only: robot agents use it.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import NoReturn

EXIT_BAD_INPUT = 2


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
