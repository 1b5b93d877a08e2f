"""Enforced decentralization (``sim.acl: true``): Zenoh access control generated from the graph.

With ``sim.acl`` the sim server's router denies everything by default and allows each robot's agent,
identified by a Zenoh user name and password (``usrpwd`` authentication), exactly what its place in the
graph needs. Agent i (user ``robot-<i>``) may, through the router:

- subscribe to its own pose ``robot/<i>/pose``, its own sensor reading ``robot/<i>/sense`` (scenarios
  with ``safety``), its own radio inbox ``robot/<i>/inbox`` (disk graphs: ``sim_server.radio``) and its
  neighbours' messages ``agent/<j>/msg`` (``declare_subscriber`` in, ``put`` out); on a disk graph it
  has no graph neighbours: only the server hears the messages, and relays each robot what it hears;
- publish its command ``robot/<i>/cmd`` and its message ``agent/<i>/msg`` (``put`` in). Zenoh clients
  only send a sample once the router has told them that someone subscribes to it, so the router must
  also pass them the declarations of those subscribers (``declare_subscriber`` out on ``robot/*/cmd``
  and ``agent/*/msg``, the server's subscriptions, ``robot/<i>/cmd`` and ``agent/<i>/msg``); a
  declaration carries no data;
- declare its liveliness token ``alive/agent/<i>`` and watch the sim's and its neighbours' tokens;
- query its own configuration ``config/<i>`` (also as ``swarm/*/config/<i>``, the run-id discovery).

Anything else (another robot's pose or command key, a wildcard over the run, a non-neighbour's message
or token) is dropped by the router; a client without valid credentials cannot open a session at all.
The server's own session is the router itself: access control filters what crosses its links to
remote sessions, never what it delivers locally, so the server still sees every command and token.

Flows are seen from the router: ``ingress`` is what a client sends to it, ``egress`` what it sends to
a client. Measured with eclipse-zenoh 1.10.2 (``tests/test_acl.py``).

Credentials: :func:`write_credentials` draws one random password per robot (``secrets``, deliberately
not seeded: a reproducible password protects nothing) and writes the router's dictionary
``users.txt`` and one ``robot-<i>.cred`` per robot, each ``user:password`` on one line, mode 0600 in a
0700 directory. ``python -m swarm.runtime.acl credentials --robots N --out DIR`` does the same by hand.

Importable by a robot agent (standard library and :mod:`swarm.runtime.wire` only).
"""

from __future__ import annotations

import os
import secrets
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from swarm.runtime.usage import EXIT_BAD_INPUT, OneLineArgumentParser
from swarm.runtime.wire import Keys

USERS_FILE = "users.txt"
ROBOT_PLACEHOLDER = "{robot}"
"""In an agent's ``--credentials`` path, replaced by its robot id (one file per robot)."""


class CredentialsError(ValueError):
    """A credentials file that cannot be used; the message is one line for the user."""


def user_of(robot: int) -> str:
    """The Zenoh user name of robot ``robot``'s agent."""
    return f"robot-{int(robot)}"


def robot_rules(
    keys: Keys, robot: int, neighbours: Sequence[int], ros2_keys: dict[str, list[str]] | None = None
) -> list[dict[str, Any]]:
    """The allow rules of one robot's agent (ids prefixed with its user name). ``ros2_keys``
    (``swarm.runtime.ros2.acl_key_exprs``, a sim server with ``--ros2``): its ROS 2 topics too, the pose
    it hears (``heard``), its ``cmd_vel`` (``published``) and the liveliness tokens of its own namespace
    (``tokens``)."""
    user = user_of(robot)
    ros = ros2_keys or {"heard": [], "published": [], "tokens": []}
    heard = [
        keys.pose(robot),
        keys.sense(robot),
        keys.inbox(robot),
        *(keys.msg(j) for j in neighbours),
        *ros["heard"],
    ]
    watched = [keys.alive_sim, *(keys.alive_agent(j) for j in neighbours)]
    configs = [keys.config(robot), Keys.any_run_config(robot)]

    def rule(name: str, flow: str, messages: list[str], key_exprs: list[str]) -> dict[str, Any]:
        return {
            "id": f"{user}/{name}",
            "permission": "allow",
            "flows": [flow],
            "messages": messages,
            "key_exprs": key_exprs,
        }

    return [
        rule("subscribe", "ingress", ["declare_subscriber"], heard),
        rule("receive", "egress", ["put"], heard),
        rule("publish", "ingress", ["put"], [keys.cmd(robot), keys.msg(robot), *ros["published"]]),
        rule(
            "publish-matching",
            "egress",
            ["declare_subscriber"],
            [keys.all_cmds, keys.all_msgs, keys.cmd(robot), keys.msg(robot), *ros["published"]],
        ),
        rule("token", "ingress", ["liveliness_token"], [keys.alive_agent(robot), *ros["tokens"]]),
        rule("watch", "ingress", ["declare_liveliness_subscriber", "liveliness_query"], watched),
        rule("watch-receive", "egress", ["liveliness_token"], watched),
        rule("config", "ingress", ["query"], configs),
        rule("config-reply", "egress", ["reply"], [keys.config(robot)]),
    ]


def access_control(
    keys: Keys, adjacency: Sequence[Sequence[float]], ros2_keys: Sequence[dict[str, list[str]]] | None = None
) -> dict[str, Any]:
    """Zenoh's ``access_control`` block for a run on a fixed graph: default deny, one subject (a
    user name) and one policy per robot (``ros2_keys[i]``: robot i's ROS 2 keys, :func:`robot_rules`)."""
    rules, subjects, policies = [], [], []
    for robot, row in enumerate(adjacency):
        neighbours = [j for j, weight in enumerate(row) if weight and j != robot]
        own = robot_rules(keys, robot, neighbours, None if ros2_keys is None else ros2_keys[robot])
        rules += own
        subjects.append({"id": user_of(robot), "usernames": [user_of(robot)]})
        policies.append(
            {"id": user_of(robot), "rules": [rule["id"] for rule in own], "subjects": [user_of(robot)]}
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def router_settings(
    keys: Keys,
    adjacency: Sequence[Sequence[float]],
    users_file: Path,
    ros2_keys: Sequence[dict[str, list[str]]] | None = None,
) -> dict[str, Any]:
    """Settings of the sim server's router session (for ``wire.session_config``)."""
    return {
        "transport/auth/usrpwd": {"dictionary_file": str(users_file)},
        "access_control": access_control(keys, adjacency, ros2_keys),
    }


def client_settings(user: str, password: str) -> dict[str, Any]:
    """Settings of an agent's client session (for ``wire.session_config``)."""
    return {"transport/auth/usrpwd": {"user": user, "password": password}}


def _write_private(path: Path, text: str) -> None:
    """Write ``text`` to a file only its owner can read (created 0600, never world-readable)."""
    path.unlink(missing_ok=True)
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(descriptor, "w") as file:
        file.write(text)


def write_credentials(directory: Path, count: int) -> tuple[Path, str]:
    """Fresh credentials for robots ``0..count-1``: the router's dictionary and one file per robot.

    Returns the dictionary's path and the per-robot path with :data:`ROBOT_PLACEHOLDER`.
    """
    directory = Path(directory)
    directory.mkdir(mode=0o700, parents=True, exist_ok=True)
    directory.chmod(0o700)
    lines = []
    for robot in range(count):
        line = f"{user_of(robot)}:{secrets.token_urlsafe(24)}\n"
        lines.append(line)
        _write_private(directory / f"{user_of(robot)}.cred", line)
    users = directory / USERS_FILE
    _write_private(users, "".join(lines))
    return users, str(directory / f"robot-{ROBOT_PLACEHOLDER}.cred")


def read_credentials(path: str | Path, robot: int) -> tuple[str, str]:
    """``(user, password)`` of robot ``robot`` from a ``user:password`` file: the line of its user name,
    or the only line. ``{robot}`` in ``path`` is replaced by the robot id."""
    path = Path(str(path).replace(ROBOT_PLACEHOLDER, str(int(robot))))
    try:
        lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
    except FileNotFoundError:
        raise CredentialsError(f"{path}: no such credentials file") from None
    except (OSError, UnicodeDecodeError) as error:
        raise CredentialsError(f"{path}: cannot read the credentials: {error}") from None
    pairs = [line.partition(":") for line in lines]
    if not pairs or any(not user or not sep or not password for user, sep, password in pairs):
        raise CredentialsError(f"{path}: expected lines of user:password")
    mine = [(user, password) for user, _, password in pairs if user == user_of(robot)]
    if len(mine) == 1:
        return mine[0]
    if len(pairs) == 1:
        return pairs[0][0], pairs[0][2]
    raise CredentialsError(f"{path}: no line for user {user_of(robot)}")


def main(argv: list[str] | None = None) -> int:
    parser = OneLineArgumentParser(
        prog="python -m swarm.runtime.acl",
        description="Write credentials for a run with sim.acl: the sim server's users file (--users) and "
        "one robot-<i>.cred per robot (robot-agent --credentials DIR/robot-{robot}.cred).",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    credentials = commands.add_parser("credentials", help="write fresh random credentials")
    credentials.add_argument("--robots", type=int, required=True, help="robot count N")
    credentials.add_argument("--out", required=True, help="directory (created 0700)")
    args = parser.parse_args(argv)
    if args.robots < 1:
        print("python -m swarm.runtime.acl: error: --robots must be at least 1", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        users, per_robot = write_credentials(Path(args.out), args.robots)
    except OSError as error:
        print(f"python -m swarm.runtime.acl: error: {args.out}: {error.strerror}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(f"sim server: --users {users}\nagents:     --credentials {per_robot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
