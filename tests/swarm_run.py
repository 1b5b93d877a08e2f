"""``swarm run`` started as a user starts it, in its own process from the project root, for the
tests that act beside a run (a rogue, a forger, a fuzzer, Ctrl-C): its stdout and stderr piped."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parent.parent


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(scenario: Path, out: Path, *options: str, interruptible: bool = False) -> subprocess.Popen:
    """``swarm run SCENARIO --out OUT --quiet [OPTIONS]``. ``interruptible``: SIGINT reaches it as
    from a terminal (a suite started in the background, ``cmd &``, ignores SIGINT, and an ignored
    signal is inherited, so a Ctrl-C test would see nothing)."""
    return subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", str(scenario), "--out", str(out), "--quiet", *options],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=PROJECT_ROOT,
        preexec_fn=_default_sigint if interruptible else None,
    )
