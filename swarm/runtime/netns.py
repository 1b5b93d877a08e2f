"""Several hosts on one Linux machine: network namespaces joined by a bridge (tests and benchmarks).

``Hosts(["sim", "robots"])`` creates one network namespace per host and one more holding a bridge
(the "switch"); each host is joined to it by a veth pair, gets the address ``<subnet>.<k + 1>/24``
on its end and its loopback up. ``delay(host, ms)`` adds a netem delay to both directions of that
host's link (``tc``), ``link_up(host, False)`` cuts it. Everything is deleted at the end of the
``with`` block (deleting a namespace deletes its veth ends). Needs Linux, root (CAP_NET_ADMIN) and
``ip`` (iproute2); :func:`why_no_namespaces` says why not, and :class:`NamespaceError` carries the
reason when the kernel refuses. Addresses default to TEST-NET-1 (192.0.2.0/24, RFC 5737): they exist
only inside these namespaces.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import uuid
from pathlib import Path


class NamespaceError(RuntimeError):
    """The namespaces, links or delays cannot be made here (the message says why)."""


def why_no_namespaces() -> str | None:
    """Why network namespaces cannot be created here, or None."""
    if not sys.platform.startswith("linux"):
        return "network namespaces need Linux"
    if os.geteuid() != 0:
        return "creating network namespaces needs root (CAP_NET_ADMIN)"
    if shutil.which("ip") is None:
        return "creating network namespaces needs the `ip` command (iproute2)"
    return None


def _run(*command: str) -> None:
    try:
        subprocess.run(list(command), check=True, capture_output=True, text=True, timeout=10)
    except subprocess.CalledProcessError as error:
        raise NamespaceError(f"`{' '.join(command)}` failed: {error.stderr.strip()}") from None
    except (OSError, subprocess.TimeoutExpired) as error:
        raise NamespaceError(f"`{' '.join(command)}` failed: {error}") from None


def ip(*args: str) -> None:
    """Run ``ip ARGS``; :class:`NamespaceError` with its message when it fails."""
    _run("ip", *args)


class Hosts:
    """Emulated hosts (one network namespace each) on one bridge; a context manager."""

    def __init__(self, names: list[str], subnet: str = "192.0.2"):
        if len(set(names)) != len(names) or not 1 <= len(names) <= 200:
            raise ValueError(f"host names must be 1 to 200 distinct names, got {names}")
        self.names = list(names)
        self.subnet = subnet
        self.tag = uuid.uuid4().hex[:6]
        self.switch = f"swarm-sw-{self.tag}"
        self._created: list[str] = []

    def namespace(self, host: str) -> str:
        return f"swarm-{self.names.index(host)}-{self.tag}"

    def address(self, host: str) -> str:
        return f"{self.subnet}.{self.names.index(host) + 1}"

    def interface(self, host: str) -> str:
        """The host's end of its link (interface names: at most 15 characters)."""
        return f"swh{self.names.index(host)}{self.tag}"

    def _port(self, host: str) -> str:
        return f"sws{self.names.index(host)}{self.tag}"

    def __enter__(self) -> Hosts:
        reason = why_no_namespaces()
        if reason:
            raise NamespaceError(reason)
        try:
            ip("netns", "add", self.switch)
            self._created.append(self.switch)
            ip("-n", self.switch, "link", "add", "br0", "type", "bridge")
            ip("-n", self.switch, "link", "set", "br0", "up")
            for host in self.names:
                namespace, interface, port = self.namespace(host), self.interface(host), self._port(host)
                ip("netns", "add", namespace)
                self._created.append(namespace)
                ip("link", "add", interface, "netns", namespace, "type", "veth", "peer", "name", port)
                ip("link", "set", port, "netns", self.switch)
                ip("-n", self.switch, "link", "set", port, "master", "br0")
                ip("-n", self.switch, "link", "set", port, "up")
                ip("-n", namespace, "addr", "add", f"{self.address(host)}/24", "dev", interface)
                ip("-n", namespace, "link", "set", interface, "up")
                ip("-n", namespace, "link", "set", "lo", "up")
        except NamespaceError:
            self.close()
            raise
        return self

    def delay(self, host: str, delay_ms: float) -> None:
        """A netem delay of ``delay_ms`` on both directions of ``host``'s link (needs ``tc``)."""
        if shutil.which("tc") is None:
            raise NamespaceError("a link delay needs the `tc` command (iproute2)")
        for namespace, device in (
            (self.namespace(host), self.interface(host)),
            (self.switch, self._port(host)),
        ):
            _run(
                "tc",
                "-n",
                namespace,
                "qdisc",
                "add",
                "dev",
                device,
                "root",
                "netem",
                "delay",
                f"{delay_ms:g}ms",
            )

    def link_up(self, host: str, up: bool) -> None:
        """Bring ``host``'s end of its link up or down (a network partition)."""
        ip("-n", self.namespace(host), "link", "set", self.interface(host), "up" if up else "down")

    def tx_bytes(self, host: str) -> int:
        """Bytes ``host`` has sent over its link."""
        path = f"/sys/class/net/{self.interface(host)}/statistics/tx_bytes"
        command = ["ip", "netns", "exec", self.namespace(host), "cat", path]
        return int(subprocess.run(command, capture_output=True, text=True, check=True, timeout=10).stdout)

    def command(self, host: str, *command: str) -> list[str]:
        """``command`` run inside ``host``'s namespace."""
        return ["ip", "netns", "exec", self.namespace(host), *command]

    def close(self) -> None:
        for namespace in reversed(self._created):
            subprocess.run(["ip", "netns", "del", namespace], capture_output=True, timeout=10)
        self._created.clear()

    def __exit__(self, *exc: object) -> None:
        self.close()


class Processes:
    """Python commands started inside a host's namespace, each in its own process group, output to
    ``<log_dir>/<name>.out``; :meth:`stop` kills every group still running."""

    def __init__(self, hosts: Hosts, log_dir: Path, cwd: Path | None = None):
        self.hosts, self.log_dir, self.cwd = hosts, log_dir, cwd
        self.started: dict[str, subprocess.Popen] = {}

    def start(
        self, name: str, host: str, *command: str, env: dict[str, str] | None = None
    ) -> subprocess.Popen:
        with open(self.log_dir / f"{name}.out", "wb") as log:
            process = subprocess.Popen(
                self.hosts.command(host, sys.executable, *command),
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                cwd=self.cwd,
                env=env,
                start_new_session=True,
            )
        self.started[name] = process
        return process

    def stop(self) -> None:
        for process in self.started.values():
            if process.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGKILL)
                process.wait(timeout=10)

    def log(self, name: str) -> str:
        return (self.log_dir / f"{name}.out").read_text(errors="replace")[-2000:]
