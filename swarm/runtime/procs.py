"""Operating-system process helpers of the distributed runtime: free ports, process groups, parent death.

The runner starts the sim server and the agents each in a process group of their own, so that one
``killpg`` reaches a launcher and every agent it forked; children ask the kernel to signal them
when their parent dies, so that not even a SIGKILLed runner leaves processes behind.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import shlex
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterable

log = logging.getLogger(__name__)

_PR_SET_PDEATHSIG = 1


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago (the OS picks it; another process may race for it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def die_with_parent(sig: int = signal.SIGTERM) -> None:
    """Linux: have the kernel send ``sig`` to this process when its parent exits (elsewhere: nothing)."""
    if not sys.platform.startswith("linux"):
        return
    parent = os.getppid()
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    if os.getppid() != parent or parent == 1:  # the parent died before prctl took effect
        os.kill(os.getpid(), sig)


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def signal_groups(pgids: Iterable[int], sig: int) -> None:
    for pgid in pgids:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pgid, sig)


def stop_groups(pgids: Iterable[int], grace_s: float = 3.0, reap: object = None) -> list[int]:
    """SIGTERM every group, wait up to ``grace_s`` for them to end, SIGKILL what is left.

    ``reap`` is called while waiting (e.g. to ``poll()`` the direct children so that they do not
    linger as zombies). Returns the groups that had to be killed.
    """
    pgids = list(pgids)
    signal_groups(pgids, signal.SIGTERM)
    signal_groups(pgids, signal.SIGCONT)  # a stopped process (a hang_agent fault) must run to exit
    deadline = time.monotonic() + grace_s
    while time.monotonic() < deadline:
        if callable(reap):
            reap()
        if not any(group_alive(pgid) for pgid in pgids):
            return []
        time.sleep(0.02)
    killed = [pgid for pgid in pgids if group_alive(pgid)]
    signal_groups(killed, signal.SIGKILL)
    if callable(reap):
        for _ in range(50):
            reap()
            if not any(group_alive(pgid) for pgid in killed):
                break
            time.sleep(0.02)
    return killed


class Supervisor:
    """Starts commands each in a new session (process group) with output to a log file, and
    stops every group it started when the ``with`` block ends, however it ends."""

    def __init__(self, env: dict[str, str] | None = None, grace_s: float = 3.0):
        self.env = env
        self.grace_s = grace_s
        self.processes: dict[str, subprocess.Popen] = {}
        self.killed: list[int] = []

    def start(self, name: str, command: list[str], log_path: os.PathLike | str) -> subprocess.Popen:
        with open(log_path, "wb") as log_file:
            process = subprocess.Popen(
                command,
                stdin=subprocess.DEVNULL,
                stdout=log_file,
                stderr=subprocess.STDOUT,
                env=self.env,
                start_new_session=True,
            )
        self.processes[name] = process
        log.debug("started %s (pid %d, log %s): %s", name, process.pid, log_path, shlex.join(command))
        return process

    def poll_all(self) -> None:
        for process in self.processes.values():
            process.poll()

    def wait(self, name: str, timeout_s: float) -> int | None:
        """Exit status of ``name`` once it ended, or None after ``timeout_s``."""
        try:
            return self.processes[name].wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def stop(self) -> None:
        pgids = [process.pid for process in self.processes.values()]
        self.killed = stop_groups(pgids, self.grace_s, reap=self.poll_all)

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
