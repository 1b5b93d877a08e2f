"""Zenoh's TLS transport with a per-run certificate authority, for runs over several hosts.

Access control (``swarm.runtime.acl``) says who may do what once a session is open; over a network
the link itself must also be private and must prove who is at each end. :func:`write_tls` makes a
fresh certificate authority for one run (an ECDSA P-256 key, never written: no one can sign with it
after the run), the sim server's certificate (its host names and addresses as subject alternative
names, so that agents verify the name they connect to) and one client certificate per robot (common
name ``robot-<i>``). The sim server's router listens on ``tls/HOST:PORT`` and requires every client
to present a certificate of that CA (mutual TLS: ``enable_mtls``, which a client needs too, or it sends
no certificate: zenoh-link-tls ``utils.rs``); an agent holds only its own key.

Zenoh's configuration keys (``transport/link/tls/...``, checked against eclipse-zenoh's
``DEFAULT_CONFIG.json5`` for 1.x): ``root_ca_certificate``, ``listen_private_key``,
``listen_certificate``, ``enable_mtls``, ``connect_private_key``, ``connect_certificate``,
``verify_name_on_connect`` (left at its default, true).

Files in the directory (keys 0600, the directory 0700): ``ca.pem``, ``server.pem``, ``server.key``,
``robot-<i>.pem``, ``robot-<i>.key``. ``python -m swarm.runtime.tls certificates --robots N --host H
--out DIR`` writes them by hand; copy ``ca.pem`` and a robot's pair to that robot's host only.

Importable by a robot agent: :func:`client_settings` needs only the standard library; ``cryptography``
(the ``sim`` extra) is imported by :func:`write_tls` alone.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from swarm.runtime.usage import EXIT_BAD_INPUT, OneLineArgumentParser

CA_FILE, SERVER_CERT, SERVER_KEY = "ca.pem", "server.pem", "server.key"
VALID_DAYS = 7
"""Certificates of a run are valid this long (a run lasts minutes; a leaked key soon expires)."""


class TlsError(ValueError):
    """A TLS directory that cannot be used; the message is one line for the user."""


def robot_files(directory: Path, robot: int) -> tuple[Path, Path]:
    """Robot ``robot``'s certificate and key in ``directory``."""
    return Path(directory) / f"robot-{int(robot)}.pem", Path(directory) / f"robot-{int(robot)}.key"


def _write(path: Path, data: bytes, private: bool) -> None:
    path.unlink(missing_ok=True)
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600 if private else 0o644)
    with os.fdopen(descriptor, "wb") as file:
        file.write(data)


def write_tls(directory: Path, robots: int, hosts: Sequence[str] = ("127.0.0.1", "localhost")) -> Path:
    """A fresh CA, the server's certificate for ``hosts`` (IP addresses or DNS names) and one client
    certificate per robot ``0..robots-1``, written to ``directory`` (created 0700); returns it."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    directory = Path(directory)
    directory.mkdir(mode=0o700, parents=True, exist_ok=True)
    directory.chmod(0o700)
    now = datetime.datetime.now(datetime.timezone.utc)
    start, end = now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=VALID_DAYS)

    def name(common: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common)])

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = name("gnn-swarm run CA")
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(ca_key, hashes.SHA256())
    )
    _write(directory / CA_FILE, ca.public_bytes(serialization.Encoding.PEM), private=False)

    def leaf(common: str, usage, alt_names: list) -> tuple[bytes, bytes]:
        key = ec.generate_private_key(ec.SECP256R1())
        builder = (
            x509.CertificateBuilder()
            .subject_name(name(common))
            .issuer_name(ca_name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(start)
            .not_valid_after(end)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([usage]), critical=False)
        )
        if alt_names:
            builder = builder.add_extension(x509.SubjectAlternativeName(alt_names), critical=False)
        certificate = builder.sign(ca_key, hashes.SHA256())
        pem_key = key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
        return certificate.public_bytes(serialization.Encoding.PEM), pem_key

    alt: list = []
    for host in hosts:
        try:
            alt.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            alt.append(x509.DNSName(host))
    cert, key = leaf("sim-server", ExtendedKeyUsageOID.SERVER_AUTH, alt)
    _write(directory / SERVER_CERT, cert, private=False)
    _write(directory / SERVER_KEY, key, private=True)
    for robot in range(robots):
        cert, key = leaf(f"robot-{robot}", ExtendedKeyUsageOID.CLIENT_AUTH, [])
        cert_path, key_path = robot_files(directory, robot)
        _write(cert_path, cert, private=False)
        _write(key_path, key, private=True)
    return directory


def _existing(*paths: Path) -> list[str]:
    for path in paths:
        if not path.is_file():
            raise TlsError(f"{path}: no such file (python -m swarm.runtime.tls certificates writes it)")
    return [str(path.resolve()) for path in paths]


def router_settings(directory: Path | str) -> dict[str, Any]:
    """The sim server's router: its certificate and key, and mutual TLS against the run's CA."""
    directory = Path(directory)
    ca, cert, key = _existing(directory / CA_FILE, directory / SERVER_CERT, directory / SERVER_KEY)
    return {
        "transport/link/tls/root_ca_certificate": ca,
        "transport/link/tls/listen_certificate": cert,
        "transport/link/tls/listen_private_key": key,
        "transport/link/tls/enable_mtls": True,
    }


def client_settings(directory: Path | str, robot: int) -> dict[str, Any]:
    """Robot ``robot``'s agent: the run's CA (to verify the server) and its own certificate and key."""
    directory = Path(directory)
    ca, cert, key = _existing(directory / CA_FILE, *robot_files(directory, robot))
    return {
        "transport/link/tls/root_ca_certificate": ca,
        "transport/link/tls/connect_certificate": cert,
        "transport/link/tls/connect_private_key": key,
        "transport/link/tls/enable_mtls": True,  # else a client sends no certificate (zenoh-link-tls)
    }


def main(argv: list[str] | None = None) -> int:
    parser = OneLineArgumentParser(
        prog="python -m swarm.runtime.tls",
        description="Write a run's TLS certificates: a fresh CA, the sim server's (for --host) and one per "
        "robot (sim_server --tls DIR, robot-agent --tls DIR; endpoints tls/HOST:PORT).",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    certificates = commands.add_parser("certificates", help="write fresh certificates")
    certificates.add_argument("--robots", type=int, required=True, help="robot count N")
    certificates.add_argument(
        "--host", action="append", required=True, help="the sim host's address or name, repeatable"
    )
    certificates.add_argument("--out", required=True, help="directory (created 0700)")
    args = parser.parse_args(argv)
    if args.robots < 1:
        print("python -m swarm.runtime.tls: error: --robots must be at least 1", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        directory = write_tls(Path(args.out), args.robots, args.host)
    except OSError as error:
        print(f"python -m swarm.runtime.tls: error: {args.out}: {error.strerror}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(
        f"sim server: --tls {directory} --listen tls/<host>:<port>\n"
        f"agents:     --tls {directory} --connect tls/<host>:<port>"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
