"""Scenario files: one YAML file says everything about a run (docs/design.md, "Scenarios").

The whole schema is the pydantic model ``Scenario``; ``load_scenario`` turns any
problem with a file into one ``ScenarioError`` line naming the file, the key and
the reason.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, Union

import numpy as np
import yaml
from pydantic import (
    AliasChoices,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from swarm.core import graphs, metrics, tasks, topologies
from swarm.core.faults import FAULT_KINDS
from swarm.core.obstacles import ObstacleSpec
from swarm.core.robot import RobotParams
from swarm.core.safety import (
    ENGINE_MARGIN_M,
    SafetyParams,
    body_distance_m,
    gain_is_exact,
    min_sensing_radius_m,
    with_engine_margin,
)
from swarm.sim.controller_kinds import CONTROLLER_KINDS

DEFAULT_MODEL_NAME = "gnn_default.npz"  # in <project root>/models, for controller gnn without a model


class ScenarioError(ValueError):
    """A scenario that cannot run; the message is one line for the user."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


def _one_of(value: str, registered: tuple[str, ...] | list[str]) -> str:
    """``value`` if it is registered, else the error pydantic gives a Literal field."""
    if value not in registered:
        *first, last = (repr(name) for name in registered)
        raise ValueError(f"Input should be {', '.join(first)} or {last}")
    return value


class RandomInit(_Strict):
    """Every robot uniform in a box, heading uniform, at least ``min_separation_m`` apart."""

    seed: int = 0
    x: tuple[float, float] = (-2.0, 2.0)
    y: tuple[float, float] = (-2.0, 2.0)
    theta: tuple[float, float] = (-math.pi, math.pi)
    min_separation_m: float = Field(
        0.4, ge=0, validation_alias=AliasChoices("min_separation_m", "min_separation")
    )

    @field_validator("x", "y", "theta")
    @classmethod
    def _ordered(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not value[0] <= value[1]:
            raise ValueError(f"range must be [low, high] with low <= high, got {list(value)}")
        return value


class InitSpec(_Strict):
    random: RandomInit | None = None
    poses: list[tuple[float, float, float]] | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> InitSpec:
        if (self.random is None) == (self.poses is None):
            raise ValueError("give exactly one of 'random' and 'poses'")
        return self


class RobotsSpec(_Strict):
    count: int = Field(ge=1)
    init: InitSpec = Field(default_factory=lambda: InitSpec(random=RandomInit()))


class TopologySpec(_Strict):
    """The scenario's graph: one kind of ``swarm.core.topologies`` and the parameters it reads."""

    kind: str
    p: float | None = Field(None, ge=0, le=1, description="edge probability (random)")
    seed: int = 0
    connected: bool = False
    radius_m: float | None = Field(None, gt=0, validation_alias=AliasChoices("radius_m", "radius"))
    adjacency: list[list[float]] | None = None

    @field_validator("kind")
    @classmethod
    def _registered(cls, value: str) -> str:
        return _one_of(value, topologies.kinds())

    @field_validator("adjacency")
    @classmethod
    def _valid_matrix(cls, value: list[list[float]] | None) -> list[list[float]] | None:
        if value is not None:
            graphs.validate_adjacency(value)
        return value

    @model_validator(mode="after")
    def _kind_parameters(self) -> TopologySpec:
        required = topologies.get(self.kind).requires
        for attribute, key in required:
            if getattr(self, attribute) is None:
                raise ValueError(f"kind '{self.kind}' needs '{key}'")
        if self.adjacency is not None and ("adjacency", "adjacency") not in required:
            takes = " or ".join(repr(kind) for kind in topologies.kinds() if self._takes_matrix(kind))
            raise ValueError(f"'adjacency' is only for kind {takes}, not '{self.kind}'")
        return self

    @staticmethod
    def _takes_matrix(kind: str) -> bool:
        return ("adjacency", "adjacency") in topologies.get(kind).requires

    @property
    def proximity(self) -> bool:
        """No fixed graph: recomputed from the positions (``radius_m``) every tick."""
        return topologies.get(self.kind).proximity


class ControllerSpec(_Strict):
    """``controller``: a kind of ``swarm.sim.controller_kinds`` and the options that kind takes."""

    kind: str = "gnn"
    model: str | None = None
    gain: float = Field(1.0, gt=0, description="consensus gain K in 1/s (thesis eq. 3.1)")
    directions: int = Field(16, ge=3, le=256, description="mec_flood: number M of flooded directions")
    reverse: bool = Field(True, description="mec_flood, centralized_mec: drive backwards to a target behind")
    spacing_m: float | None = Field(
        None, gt=0, description="pack_flood: slot spacing (default 2(r + l) + 0.05)"
    )
    cell_radius_m: float | None = Field(
        None, gt=0, description="lloyd_local: cut each cell to this radius (half a disk graph's radius)"
    )
    horizon_ticks: int | None = Field(
        None,
        ge=0,
        description="lloyd_predict: extrapolate a flooded position toward its target over at most this many"
        " ticks of its age (default 5; 0: lloyd_flood's cell)",
    )
    step_fraction: float = Field(
        1.0,
        gt=0,
        le=1,
        description="lloyd_local, lloyd_flood, lloyd_predict: the fraction of the way to its cell's centroid"
        " a robot goes in one tick when within reach (1: the whole way; below 1 damps the swings that stale"
        " positions cause under packet loss)",
    )

    @field_validator("kind")
    @classmethod
    def _known_kind(cls, value: str) -> str:
        if value not in CONTROLLER_KINDS:
            raise ValueError(f"unknown controller '{value}' (known: {', '.join(CONTROLLER_KINDS)})")
        return value

    @model_validator(mode="after")
    def _options_of_kind(self) -> ControllerSpec:
        # model and gain predate the registry and stay accepted (and unused) by every kind
        takes = CONTROLLER_KINDS[self.kind].options
        options = ("directions", "reverse", "spacing_m", "cell_radius_m", "horizon_ticks", "step_fraction")
        for option in options:
            default = type(self).model_fields[option].default
            if getattr(self, option) != default and option not in takes:
                taken = ", ".join(takes) or "no options"
                raise KeyedError((option,), f"not an option of controller '{self.kind}' (it takes: {taken})")
        return self

    @property
    def central(self) -> bool:
        """Runs as one central process in the distributed runtime (it needs every robot's pose)."""
        return CONTROLLER_KINDS[self.kind].central


class SimSpec(_Strict):
    engine: Literal["kinematic", "pybullet"] = "pybullet"
    mode: Literal["lockstep", "realtime"] = "lockstep"
    control_period_s: float = Field(
        0.05, gt=0, le=1.0, validation_alias=AliasChoices("control_period_s", "control_period")
    )
    duration_s: float = Field(20.0, gt=0, validation_alias=AliasChoices("duration_s", "duration"))
    physics_hz: float = Field(240.0, gt=0)
    solver_iterations: int = Field(10, ge=1)
    # Distributed runtime (pybullet engine); see sim_server/server.py and robot_agent/agent.py.
    deadline_s: float = Field(
        1.0,
        gt=0,
        validation_alias=AliasChoices("deadline_s", "deadline"),
        description="lockstep: longest the sim waits for the live agents' commands of a tick",
    )
    neighbour_deadline_s: float = Field(
        0.5,
        ge=0,
        validation_alias=AliasChoices("neighbour_deadline_s", "neighbour_deadline"),
        description="lockstep: longest an agent waits for its live neighbours' messages of the last tick",
    )
    watchdog_s: float = Field(
        0.25,
        gt=0,
        validation_alias=AliasChoices("watchdog_s", "watchdog"),
        description="a robot whose commands stop for this long (sim time in lockstep) is stopped",
    )
    server_lost_s: float = Field(
        5.0,
        ge=0,
        validation_alias=AliasChoices("server_lost_s", "server_lost"),
        description="how long an agent waits for the sim's liveliness token to come back (a network"
        " partition, a frozen agent) before it takes the sim as gone and exits",
    )
    message_max_age_ticks: int | None = Field(
        None,
        ge=1,
        description="a neighbour message is usable while its age beyond the link's delay is at most this"
        " many ticks (None: 1 in lockstep, only the message of tick k-1-delay; 10 in realtime); see"
        " swarm/core/faults.py",
    )
    acl: bool | None = Field(
        None,
        description="pybullet engine: enforce the decentralization with Zenoh access control"
        " (swarm/runtime/acl.py): the sim server's router admits only agents with the run's credentials,"
        " each to its own pose,"
        " command and token and its graph neighbours' messages and tokens. Unset (the default): on in"
        " every run swarm run starts where it can be (a fixed graph, one process per robot: see"
        " Scenario.access_control_unavailable); false: off, an explicit opt-in that swarm run warns about",
    )


FAULT_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    kind: (fault.required, fault.optional) for kind, fault in FAULT_KINDS.items()
}
"""Which keys each fault kind takes (``swarm.core.faults.FAULT_KINDS``); keys by their short names."""

_FAULT_KEY_NAMES = {
    "at": ("at", "at_s"),
    "until": ("until", "until_s"),
    "duration": ("duration", "duration_s"),
}


class KeyedError(ValueError):
    """A validation error about one key below the model that raises it: ``describe_validation_error``
    names ``key`` after the model's location (``faults[2].link: ...``)."""

    def __init__(self, key: tuple[str | int, ...], message: str):
        super().__init__(message)
        self.key = key


class FaultSpec(_Strict):
    """One fault (README, "Faults"). Link faults (``drop_link``, ``restore_link``, ``packet_loss``,
    ``delay``) act in the receiving robots (``swarm.core.faults``); process faults (``kill_agent``,
    ``hang_agent``, ``restart_agent``, ``kill_server``) are done by the runner of the pybullet engine."""

    kind: str  # a key of swarm.core.faults.FAULT_KINDS
    at_s: float | None = Field(None, ge=0, validation_alias=AliasChoices("at_s", "at"))
    until_s: float | None = Field(None, gt=0, validation_alias=AliasChoices("until_s", "until"))
    link: tuple[int, int] | None = None
    direction: Literal["both", "one"] | None = Field(
        None, description="link faults: both (default) or one, only link[1] stops hearing link[0]"
    )
    p: float | None = Field(None, ge=0, le=1)
    ticks: int | None = Field(
        None, ge=1, description="delay: extra ticks of age of the newest usable message"
    )
    robot: int | None = Field(None, ge=0)
    duration_s: float | None = Field(None, gt=0, validation_alias=AliasChoices("duration_s", "duration"))

    @field_validator("kind")
    @classmethod
    def _registered(cls, value: str) -> str:
        return _one_of(value, list(FAULT_KINDS))

    @model_validator(mode="before")
    @classmethod
    def _keys_of_kind(cls, data: object) -> object:
        """Required and refused keys per kind, named as written (a null value counts as absent)."""
        if not isinstance(data, dict) or data.get("kind") not in FAULT_KEYS:
            return data
        kind = data["kind"]
        required, optional = FAULT_KEYS[kind]
        given = {}
        for key, value in data.items():
            if value is None or key == "kind":
                continue
            short = next((name for name, spellings in _FAULT_KEY_NAMES.items() if key in spellings), key)
            given[short] = key
        for key in required:
            if key not in given:
                raise KeyedError((key,), f"required for kind {kind}")
        for short, written in given.items():
            if short not in required and short not in optional and short in cls._short_keys():
                raise KeyedError(
                    (written,), f"not a key of kind {kind} (it takes {', '.join(required + optional)})"
                )
        if "direction" in given and "link" not in given:
            raise KeyedError((given["direction"],), "needs 'link'")
        return data

    @staticmethod
    def _short_keys() -> set[str]:
        return {"at", "until", "link", "direction", "p", "ticks", "robot", "duration"}

    @model_validator(mode="after")
    def _consistent(self) -> FaultSpec:
        if self.link is not None and self.link[0] == self.link[1]:
            raise KeyedError(("link",), f"a link joins two different robots, got {list(self.link)}")
        if self.until_s is not None and self.until_s <= (self.at_s or 0.0):
            raise KeyedError(("until",), f"must be after 'at' ({self.at_s or 0.0:g} s), got {self.until_s:g}")
        return self


class EngineThresholds(_Strict):
    """A threshold per engine: robots have bodies in PyBullet and cannot gather as tightly."""

    kinematic: float = Field(gt=0)
    pybullet: float = Field(gt=0)


class SuccessSpec(_Strict):
    metric: str = "max_pairwise"  # a key of swarm.core.metrics.METRICS
    threshold: float | EngineThresholds = Field(
        0.2, description="metric value in metres that counts as consensus, or one per engine"
    )

    @field_validator("metric")
    @classmethod
    def _registered(cls, value: str) -> str:
        return _one_of(value, list(metrics.METRICS))

    @field_validator("threshold")
    @classmethod
    def _positive(cls, value: float | EngineThresholds) -> float | EngineThresholds:
        if isinstance(value, float | int) and value <= 0:
            raise ValueError(f"must be greater than 0, got {value}")
        return value

    def threshold_for(self, engine: str) -> float:
        if isinstance(self.threshold, EngineThresholds):
            return getattr(self.threshold, engine)
        return float(self.threshold)


class Ros2Spec(_Strict):
    """``ros2``: how the robots appear as ROS 2 topics (``robot-agent --ros2``, ``sim_server --ros2``;
    docs/ros2.md). ``namespace``: a template, ``{i}`` the robot id."""

    domain_id: int = Field(0, ge=0, le=232, description="ROS_DOMAIN_ID of the robots")
    namespace: str = Field("robot_{i}", pattern=r"^/?[A-Za-z_{][A-Za-z0-9_{}/]*$")
    pose: Literal["odometry", "pose_stamped"] = Field(
        "odometry", description="an agent's pose: nav_msgs/Odometry (<ns>/odom) or PoseStamped (mocap)"
    )
    pose_topic: str | None = Field(None, description="topic of the pose (default <ns>/odom or <ns>/pose)")


if TYPE_CHECKING:
    TaskSection = Any
else:
    TaskSection = Annotated[Union[tasks.sections()], Field(discriminator="kind")]  # noqa: UP007
"""The ``task`` mapping: the section of one registered task (``swarm.core.tasks``), chosen by ``kind``."""


class Scenario(_Strict):
    name: str
    description: str = ""
    robots: RobotsSpec
    topology: TopologySpec
    robot: RobotParams = Field(default_factory=RobotParams)
    controller: ControllerSpec = Field(default_factory=ControllerSpec)
    sim: SimSpec = Field(default_factory=SimSpec)
    faults: list[FaultSpec] = Field(default_factory=list)
    faults_seed: int = Field(
        0,
        ge=0,
        description="seed of the packet-loss draws (swarm/core/faults.py): same seed, same packets lost",
    )
    success: SuccessSpec = Field(default_factory=SuccessSpec)
    ros2: Ros2Spec | None = None
    task: TaskSection = Field(default_factory=tasks.default_section)

    @field_validator("task", mode="before")
    @classmethod
    def _task_name(cls, value: object) -> object:
        """``task: formation`` is ``task: {kind: formation}``; an unknown kind names the known ones."""
        if isinstance(value, str):
            value = {"kind": value}
        if isinstance(value, dict) and "kind" in value:
            value = {**value, "kind": _one_of(str(value["kind"]), list(tasks.names()))}
        return value

    def _check_task(self) -> None:
        """The controller does the task; a formation has one slot per robot, tolerance under half
        their spacing (so that success is the bottleneck test, ``swarm.core.tasks.formation``)."""
        task = tasks.get(self.task.kind)
        if CONTROLLER_KINDS[self.controller.kind].task != task.name:
            takes = [name for name, kind in CONTROLLER_KINDS.items() if kind.task == task.name]
            raise KeyedError(
                ("controller", "kind"),
                f"controller '{self.controller.kind}' does not do task '{task.name}'"
                f" (it takes: {', '.join(takes)})",
            )
        if task.name == "formation":
            try:
                slots = self.task.slot_positions(self.robots.count)
            except ValueError as error:
                raise KeyedError(("task", "slots"), str(error)) from None
            from swarm.core.tasks.formation import smallest_spacing_m

            spacing = smallest_spacing_m(slots)
            if not self.task.tolerance_m < spacing / 2:
                raise KeyedError(
                    ("task", "tolerance_m"),
                    f"{self.task.tolerance_m:g} m is not under half the smallest slot spacing"
                    f" {spacing:.3g} m",
                )

    obstacles: list[ObstacleSpec] = Field(default_factory=list, description="static discs and walls")
    safety: SafetyParams | None = Field(None, description="the barrier filter (docs/safety.md); off: None")

    @model_validator(mode="after")
    def _safety_consistent(self) -> Scenario:
        """The engine's default margin (``swarm.core.safety.ENGINE_MARGIN_M``) where none is given, and
        ``pack_flood``'s slots 2 cm wider than the barrier's distance where that margin is wider than
        its default spacing allows; the sensing radius sees a body before it can reach the barrier;
        ``gamma dt <= 1``."""
        if self.safety is None:
            return self
        self.safety = with_engine_margin(self.safety, self.sim.engine)
        if self.controller.kind == "pack_flood" and self.controller.spacing_m is None:
            from swarm.sim.pack_flood import SPACING_MARGIN_M, default_spacing_m

            if self.safety.margin_m > ENGINE_MARGIN_M["kinematic"]:  # else the default: unchanged bits
                wider = (
                    body_distance_m(self.robot, self.safety) + SPACING_MARGIN_M - ENGINE_MARGIN_M["kinematic"]
                )
                self.controller.spacing_m = max(wider, default_spacing_m(self.robot))
        least = min_sensing_radius_m(self.robot, self.safety, self.sim.control_period_s)
        if self.safety.sensing_radius_m < least:
            raise KeyedError(
                ("safety", "sensing_radius_m"),
                f"{self.safety.sensing_radius_m:g} m is under {least:.3f} m, the barrier distance plus"
                " two robots' approach in one control period",
            )
        if not gain_is_exact(self.safety, self.sim.control_period_s):
            raise KeyedError(
                ("safety", "gain_per_s"),
                f"{self.safety.gain_per_s:g}/s times the control period {self.sim.control_period_s:g} s"
                " is over 1: the barrier would not hold between ticks",
            )
        return self

    @model_validator(mode="after")
    def _counts_agree(self) -> Scenario:
        count = self.robots.count
        if self.robots.init.poses is not None and len(self.robots.init.poses) != count:
            raise ValueError(
                f"robots.init.poses has {len(self.robots.init.poses)} poses but robots.count is {count}"
            )
        if self.topology.adjacency is not None and len(self.topology.adjacency) != count:
            raise ValueError(
                f"topology.adjacency is {len(self.topology.adjacency)}x{len(self.topology.adjacency)}"
                f" but robots.count is {count}"
            )
        self._check_faults()
        self._check_task()
        if self.sim.acl and self.controller.central:
            raise KeyedError(
                ("sim", "acl"),
                f"controller '{self.controller.kind}' needs every pose; access control is per robot",
            )
        return self

    def access_control_unavailable(self) -> str | None:
        """Why this run cannot have per-robot access control (None: it can)."""
        if self.controller.central:
            return f"controller '{self.controller.kind}' needs every pose"
        return None

    @property
    def access_control(self) -> bool:
        """``sim.acl`` resolved: unset means on where it is available."""
        if self.sim.acl is None:
            return self.access_control_unavailable() is None
        return self.sim.acl

    def _check_faults(self) -> None:
        """Faults name robots of this run and edges of its graph; a restore follows a drop. (Process
        faults on the kinematic engine are refused when it starts: ``swarm.runtime.runner``.)"""
        count = self.robots.count
        adjacency = None
        if any(fault.link is not None for fault in self.faults):
            try:
                adjacency = self.adjacency()
            except ValueError:
                adjacency = None  # load_scenario reports the topology itself
        down: set[tuple[int, int]] = set()  # directed links dropped so far, in time order
        order = sorted(range(len(self.faults)), key=lambda i: (self.faults[i].at_s or 0.0, i))
        for index in order:
            fault = self.faults[index]
            if fault.robot is not None and fault.robot >= count:
                raise KeyedError(
                    ("faults", index, "robot"), f"robot {fault.robot} but robots.count is {count}"
                )
            if fault.link is None:
                pass
            elif max(fault.link) >= count:
                raise KeyedError(
                    ("faults", index, "link"), f"names robot {max(fault.link)} but robots.count is {count}"
                )
            elif adjacency is not None and not adjacency[fault.link[0], fault.link[1]]:
                raise KeyedError(
                    ("faults", index, "link"),
                    f"{list(fault.link)} is not an edge of the {self.topology.kind} graph",
                )
            if fault.kind in ("drop_link", "restore_link"):
                assert fault.link is not None  # required for these kinds
                i, j = fault.link
                pairs = {(i, j)} if fault.direction == "one" else {(i, j), (j, i)}
                if fault.kind == "drop_link":
                    down |= pairs
                elif not pairs & down:
                    raise KeyedError(
                        ("faults", index, "link"),
                        f"restore_link of {list(fault.link)}, which no earlier drop_link dropped",
                    )
                else:
                    down -= pairs

    @property
    def threshold(self) -> float:
        """The success threshold for this scenario's engine."""
        return self.success.threshold_for(self.sim.engine)

    @property
    def steps(self) -> int:
        """Control ticks in the run."""
        return round(self.sim.duration_s / self.sim.control_period_s)

    def initial_poses(self) -> np.ndarray:
        """``(N, 3)`` initial axle-centre poses, reproducible from the seed."""
        from swarm.core.initial_poses import random_poses

        init = self.robots.init
        if init.poses is not None:
            return np.array(init.poses, dtype=float)
        spec = init.random
        assert spec is not None  # InitSpec holds exactly one of poses, random
        rng = np.random.default_rng(spec.seed)
        return random_poses(rng, 1, self.robots.count, spec.x, spec.y, spec.min_separation_m, spec.theta)[0]

    def adjacency(self) -> np.ndarray | None:
        """Fixed ``(N, N)`` adjacency, or None for disk graphs (recomputed from positions)."""
        return fixed_adjacency(self.topology, self.robots.count)


def fixed_adjacency(topology: TopologySpec, count: int, seed: int | None = None) -> np.ndarray | None:
    """Adjacency of a fixed topology (None for a proximity graph); ``seed`` overrides a random
    graph's seed."""
    params = topology if seed is None else topology.model_copy(update={"seed": seed})
    return topologies.build(topology.kind, count, params)


def _location(loc: tuple) -> str:
    if len(loc) > 1 and loc[0] == "task" and loc[1] in tasks.names():  # the union's tag: task.slots
        loc = (loc[0], *loc[2:])
    parts: list[str] = []
    for item in loc:
        if isinstance(item, int):
            parts.append(f"[{item}]")
        elif parts:
            parts.append(f".{item}")
        else:
            parts.append(str(item))
    return "".join(parts) or "(top level)"


def _known_keys(model: type[BaseModel], parent: tuple) -> list[str]:
    """The keys (field names and their aliases) of the model found at ``parent`` below ``model``."""
    import typing

    for part in parent:
        if isinstance(part, int):
            continue
        field = next(
            (
                info
                for name, info in model.model_fields.items()
                if part == name
                or (isinstance(info.validation_alias, AliasChoices) and part in info.validation_alias.choices)
            ),
            None,
        )
        if field is None:
            return []
        candidates = [field.annotation]
        found = None
        while candidates:  # unwrap Optional, list, tuple and unions down to a model
            annotation = candidates.pop()
            if isinstance(annotation, type) and issubclass(annotation, BaseModel):
                found = annotation
                break
            candidates.extend(typing.get_args(annotation))
        if found is None:
            return []
        model = found
    keys = []
    for name, info in model.model_fields.items():
        keys.append(name)
        if isinstance(info.validation_alias, AliasChoices):
            keys += [choice for choice in info.validation_alias.choices if isinstance(choice, str)]
    return keys


def _typo(errors: Sequence[Any]) -> dict | None:
    """An unknown key that is close to a known key (a typo), preferring one whose sibling is missing;
    the error gets ``suggestion``."""
    import difflib

    extras = [e for e in errors if e["type"] == "extra_forbidden"]
    missing = {(tuple(e["loc"][:-1]), e["loc"][-1]) for e in errors if e["type"] == "missing"}
    best = None
    for extra in extras:
        parent, key = tuple(extra["loc"][:-1]), str(extra["loc"][-1])
        siblings = [name for where, name in missing if where == parent]
        close = difflib.get_close_matches(key, [str(name) for name in siblings], n=1, cutoff=0.5)
        if close:
            return {**extra, "suggestion": close[0]}
        if best is None:
            close = difflib.get_close_matches(key, _known_keys(Scenario, parent), n=1, cutoff=0.6)
            if close:
                best = {**extra, "suggestion": close[0]}
    return best


def _describe_one(item: Any) -> str:
    """One pydantic error as ``key: reason``."""
    loc = tuple(part for part in item["loc"] if not (isinstance(part, str) and part.startswith("function-")))
    message = item["msg"].removeprefix("Value error, ")
    keyed = (item.get("ctx") or {}).get("error")
    if isinstance(keyed, KeyedError):  # an error about a key below the model that raised it
        loc = (*loc, *keyed.key)
    if item["type"] == "extra_forbidden":
        message = "unknown key"
    elif item["type"] == "missing":
        message = "required key is missing"
    return f"{_location(loc)}: {message}"


def describe_validation_error(error: ValidationError) -> str:
    """Every pydantic error as ``key: reason``, joined by ``; `` on one line; an unknown key that
    looks like a typo of a known one comes first, with the suggestion."""
    errors = list(error.errors())
    typo = _typo(errors)
    parts = []
    if typo is not None:
        key, suggestion = typo["loc"][-1], typo["suggestion"]
        parts.append(f"{_location(tuple(typo['loc']))}: unknown key '{key}', did you mean '{suggestion}'?")
        meant = (*tuple(typo["loc"])[:-1], suggestion)  # its "required key is missing" is the same mistake
        errors = [item for item in errors if tuple(item["loc"]) not in (tuple(typo["loc"]), meant)]
    parts += [_describe_one(item) for item in errors]
    return "; ".join(dict.fromkeys(parts))


def parse_scenario(data: object, source: str = "<scenario>") -> Scenario:
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: top level must be a mapping of keys, got {type(data).__name__}")
    try:
        return Scenario.model_validate(data)
    except ValidationError as error:
        raise ScenarioError(f"{source}: {describe_validation_error(error)}") from None


KINEMATIC_IGNORES = (
    "mode",
    "physics_hz",
    "solver_iterations",
    "deadline_s",
    "neighbour_deadline_s",
    "watchdog_s",
    "server_lost_s",
    "acl",
)
"""``sim`` keys of the PyBullet runtime (bodies, processes, Zenoh) that the kinematic engine ignores."""


def engine_warnings(scenario: Scenario) -> list[str]:
    """``sim`` keys set away from their default that the scenario's engine ignores, one line each."""
    warnings = []
    if scenario.sim.engine == "kinematic":
        defaults = SimSpec()
        for key in KINEMATIC_IGNORES:
            value = getattr(scenario.sim, key)
            if value != getattr(defaults, key):
                warnings.append(
                    f"sim.{key}: {value!r} does not apply to the kinematic engine (no bodies, no processes,"
                    " no network); it is ignored"
                )
    return warnings


def threshold_warnings(scenario: Scenario) -> list[str]:
    """A PyBullet threshold that the robots' bodies cannot reach
    (``swarm.core.metrics.min_gathered_max_pairwise_m``), as one line; none when it can."""
    from swarm.core import metrics

    warnings = []
    if scenario.task.kind == "rendezvous" and scenario.success.metric == "max_pairwise":  # its success
        count, radius_m = scenario.robots.count, scenario.robot.body_radius_m
        smallest_m = metrics.min_gathered_max_pairwise_m(count, radius_m)
        threshold_m = scenario.success.threshold_for("pybullet")
        if threshold_m < smallest_m and (
            scenario.sim.engine == "pybullet" or isinstance(scenario.success.threshold, EngineThresholds)
        ):
            exact = "" if count <= 8 else " at least"
            warnings.append(
                f"success.threshold: {threshold_m:g} m is below what {count} bodies of radius {radius_m:g} m"
                f" allow on the pybullet engine (max_pairwise{exact} {smallest_m:.3f} m when packed);"
                " the run cannot converge there"
            )
    return warnings


ENGINE_DEFAULTS = (("safety", "margin_m"), ("controller", "spacing_m"))
"""Keys whose default depends on ``sim.engine`` (``Scenario._safety_consistent``): a scenario run on
another engine than its file's (``swarm run --engine``) gets that engine's unless the file gives them."""


def load_scenario(path: str | Path) -> Scenario:
    """Read, validate and check a scenario file; any problem raises one ``ScenarioError`` line.
    A threshold that the bodies cannot reach is logged as a warning (``threshold_warnings``)."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such scenario file") from None
    except OSError as error:
        raise ScenarioError(f"{path}: cannot read: {error.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(error, "problem", None) or str(error).splitlines()[0]
        raise ScenarioError(f"{path}: invalid YAML{where}: {problem}") from None
    scenario = parse_scenario(data, str(path))
    # impossible placements and random graphs that cannot be made connected are bad input, found
    # before anything starts (they would otherwise surface as a traceback mid-run)
    for key, build in (("robots.init", scenario.initial_poses), ("topology", scenario.adjacency)):
        try:
            build()
        except ValueError as error:
            raise ScenarioError(f"{path}: {key}: {error}") from None
    if scenario.controller.model is not None:
        resolve_model_path(scenario.controller.model, path)
    for warning in threshold_warnings(scenario):
        logging.getLogger(__name__).warning("%s: %s", path, warning)
    return scenario


def default_model_path() -> Path:
    """The shipped default policy, ``models/gnn_default.npz`` in the project root."""
    import swarm

    path = Path(swarm.__file__).resolve().parent.parent / "models" / DEFAULT_MODEL_NAME
    if not path.is_file():
        raise ScenarioError(
            f"controller.model: not given and the default model {path} is missing (see models/README.md)"
        )
    return path


def resolve_model_path(model: str | None, scenario_path: Path | None = None) -> Path:
    """Find a model file: as given (absolute or from the current directory), then next to the
    scenario file, then in the project root above the scenario's folder; None: the default model."""
    if model is None:
        return default_model_path()
    candidates = [Path(model)]
    if scenario_path is not None and not Path(model).is_absolute():
        candidates += [scenario_path.parent / model, scenario_path.parent.parent / model]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    source = f"{scenario_path}: " if scenario_path is not None else ""
    raise ScenarioError(f"{source}controller.model: model file not found: {model}")


def policy_path(scenario: Scenario, scenario_path: Path | None = None) -> Path | None:
    """The policy file the scenario's controller runs: ``gnn``'s ``controller.model`` (default: the shipped
    ``gnn_default.npz``); for another kind that takes a model (``capt_gnn``) its ``controller.model``
    when given, else None (the kind loads its own shipped file); None for kinds without a model."""
    spec = scenario.controller
    if spec.kind == "gnn":
        return resolve_model_path(spec.model, scenario_path)
    if "model" in CONTROLLER_KINDS[spec.kind].options and spec.model is not None:
        return resolve_model_path(spec.model, scenario_path)
    return None


def dump_scenario(scenario: Scenario) -> str:
    """The resolved scenario (every default filled in) as YAML."""
    return yaml.safe_dump(scenario.model_dump(mode="json"), sort_keys=False)
