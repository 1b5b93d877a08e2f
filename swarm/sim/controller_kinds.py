"""The controller registry: every ``controller.kind`` and how each engine runs it.

One entry per kind says which scenario options it takes, how the batched kinematic engine builds it
(``swarm.sim.controllers``, numba), and how the distributed runtime runs it: on board every robot
(``swarm.sim.onboard``, numpy only) or as one central process (``robot_agent.central``). The scenario
schema, ``swarm run``, ``swarm sweep``, the sim server and the robot agents all look kinds up here.
Importing this module is cheap (no numba, no torch): the engines' classes are imported on use.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from swarm.core.robot import RobotParams


@dataclass(frozen=True)
class ControllerArgs:
    """What building a controller may need, whatever its kind (each kind reads its own)."""

    robot: RobotParams
    control_period_s: float = 0.05
    gain: float = 1.0
    directions: int = 16
    reverse: bool = True
    robot_count: int = 0
    policy: Any = None  # gnn: a policy file path (batched) or its bytes (onboard)
    task: Any = None  # the scenario's task section (swarm.core.tasks)
    robot_id: int = 0  # onboard: the robot it runs on (what a task's per-robot form needs)
    spacing_m: float | None = None  # pack_flood: slot spacing (None: its default from the robot)
    cell_radius_m: float | None = None  # lloyd_local: the cell's cut radius (None: not cut)
    horizon_ticks: int | None = None  # lloyd_predict: ticks an entry is extrapolated over (None: 5)
    step_fraction: float = 1.0  # lloyd_local/flood/predict: of the way to the centroid in one tick

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any], robot: RobotParams, control_period_s: float, **more):
        """From a scenario's ``controller`` section (a mapping, e.g. ``ControllerSpec.model_dump()``)."""
        keys = (
            *("gain", "directions", "reverse", "spacing_m"),
            *("cell_radius_m", "horizon_ticks", "step_fraction"),
        )
        options = {key: spec[key] for key in keys if spec.get(key) is not None}
        return cls(robot=robot, control_period_s=control_period_s, **options, **more)


def _local_consensus(args: ControllerArgs):
    from swarm.sim.controllers import LocalConsensus

    return LocalConsensus(args.robot, args.gain)


def _centralized(args: ControllerArgs):
    from swarm.sim.controllers import Centralized

    return Centralized(args.robot, args.gain)


def _gnn(args: ControllerArgs):
    from swarm.sim.policy import load_policy

    if args.policy is None:
        raise ValueError("controller 'gnn' needs a policy file (controller.model)")
    return load_policy(args.policy, args.robot, args.robot_count, args.control_period_s)


def _mec_flood(args: ControllerArgs):
    from swarm.sim.controllers import MecFlood

    return MecFlood(args.robot, args.control_period_s, args.directions, args.reverse)


def _centralized_mec(args: ControllerArgs):
    from swarm.sim.controllers import CentralizedMec

    return CentralizedMec(args.robot, args.control_period_s, args.reverse)


def _onboard_local_consensus(args: ControllerArgs):
    from swarm.sim.onboard import OnboardLocalConsensus

    return OnboardLocalConsensus(args.robot, args.gain)


def _onboard_gnn(args: ControllerArgs):
    from swarm.sim.onboard import onboard_policy

    return onboard_policy(args.policy, args.robot, args.robot_count, args.control_period_s)


def _onboard_mec_flood(args: ControllerArgs):
    from swarm.sim.onboard import OnboardMecFlood

    return OnboardMecFlood(args.robot, args.control_period_s, args.directions, args.reverse)


def _capt(args: ControllerArgs):
    from swarm.sim.formation_controllers import CaptExpert

    return CaptExpert(args.robot, args.control_period_s, _formation(args), args.reverse)


def _capt_flood(args: ControllerArgs):
    from swarm.sim.formation_controllers import CaptFlood

    return CaptFlood(args.robot, args.control_period_s, _formation(args), args.robot_count, args.reverse)


def _onboard_capt_flood(args: ControllerArgs):
    from swarm.sim.formation_onboard import OnboardCaptFlood

    return OnboardCaptFlood(
        args.robot, args.control_period_s, _formation(args), args.robot_count, args.robot_id, args.reverse
    )


def _pack_flood(args: ControllerArgs):
    from swarm.sim.pack_flood import PackFlood

    return PackFlood(args.robot, args.control_period_s, args.robot_count, args.spacing_m, args.reverse)


def _onboard_pack_flood(args: ControllerArgs):
    from swarm.sim.pack_flood import OnboardPackFlood

    return OnboardPackFlood(
        args.robot, args.control_period_s, args.robot_count, args.robot_id, args.spacing_m, args.reverse
    )


def _learned_weights(args: ControllerArgs, weights_class: Any, default_name: str):
    """A learned task controller's steering MLP: ``args.policy`` (a path or bytes), else the shipped
    file ``models/<default_name>``."""
    from pathlib import Path

    from swarm.sim.steering_mlp import PolicyFileError

    source = args.policy
    if source is None:
        source = Path(__file__).resolve().parent.parent.parent / "models" / default_name
    try:
        return weights_class.load(source)
    except PolicyFileError as error:
        if isinstance(source, bytes):
            raise
        raise PolicyFileError(f"{source}: {error}") from None


def _formation_weights(args: ControllerArgs):
    from swarm.sim.formation_gnn import DEFAULT_MODEL_NAME, FormationGnnWeights

    return _learned_weights(args, FormationGnnWeights, DEFAULT_MODEL_NAME)


def _capt_gnn(args: ControllerArgs):
    from swarm.sim.formation_controllers import CaptGnn

    return CaptGnn(
        args.robot,
        args.control_period_s,
        _formation(args),
        args.robot_count,
        _formation_weights(args),
        args.reverse,
    )


def _onboard_capt_gnn(args: ControllerArgs):
    from swarm.sim.formation_gnn import OnboardCaptGnn

    return OnboardCaptGnn(
        args.robot,
        args.control_period_s,
        _formation(args),
        args.robot_count,
        args.robot_id,
        _formation_weights(args),
        args.reverse,
    )


def _lloyd(args: ControllerArgs):
    from swarm.sim.coverage_controllers import LloydExpert

    return LloydExpert(args.robot, args.control_period_s, _coverage(args), args.reverse)


def _lloyd_local(args: ControllerArgs):
    from swarm.sim.coverage_controllers import LloydLocal

    return LloydLocal(
        args.robot,
        args.control_period_s,
        _coverage(args),
        args.cell_radius_m,
        args.reverse,
        args.step_fraction,
    )


def _onboard_lloyd_local(args: ControllerArgs):
    from swarm.sim.coverage_onboard import OnboardLloydLocal

    return OnboardLloydLocal(
        args.robot,
        args.control_period_s,
        _coverage(args),
        args.cell_radius_m,
        args.reverse,
        args.step_fraction,
    )


def _lloyd_flood(args: ControllerArgs):
    from swarm.sim.coverage_controllers import LloydFlood

    return LloydFlood(
        args.robot,
        args.control_period_s,
        _coverage(args),
        args.robot_count,
        args.reverse,
        args.step_fraction,
    )


def _onboard_lloyd_flood(args: ControllerArgs):
    from swarm.sim.coverage_onboard import OnboardLloydFlood

    return OnboardLloydFlood(
        args.robot,
        args.control_period_s,
        _coverage(args),
        args.robot_count,
        args.robot_id,
        args.reverse,
        args.step_fraction,
    )


def _lloyd_predict(args: ControllerArgs):
    from swarm.sim.coverage_controllers import LloydPredict

    return LloydPredict(
        args.robot,
        args.control_period_s,
        _coverage(args),
        args.robot_count,
        args.reverse,
        _horizon(args),
        args.step_fraction,
    )


def _onboard_lloyd_predict(args: ControllerArgs):
    from swarm.sim.coverage_onboard import OnboardLloydPredict

    return OnboardLloydPredict(
        args.robot,
        args.control_period_s,
        _coverage(args),
        args.robot_count,
        args.robot_id,
        args.reverse,
        _horizon(args),
        args.step_fraction,
    )


def _horizon(args: ControllerArgs) -> int:
    from swarm.sim.coverage_onboard import HORIZON_TICKS

    return HORIZON_TICKS if args.horizon_ticks is None else args.horizon_ticks


def _coverage_weights(args: ControllerArgs):
    from swarm.sim.coverage_gnn import DEFAULT_MODEL_NAME, CoverageGnnWeights

    return _learned_weights(args, CoverageGnnWeights, DEFAULT_MODEL_NAME)


def _lloyd_gnn(args: ControllerArgs):
    from swarm.sim.coverage_controllers import LloydGnn

    return LloydGnn(
        args.robot,
        args.control_period_s,
        _coverage(args),
        args.robot_count,
        _coverage_weights(args),
        args.reverse,
    )


def _onboard_lloyd_gnn(args: ControllerArgs):
    from swarm.sim.coverage_gnn import OnboardLloydGnn

    return OnboardLloydGnn(
        args.robot,
        args.control_period_s,
        _coverage(args),
        args.robot_count,
        args.robot_id,
        _coverage_weights(args),
        args.reverse,
    )


def _task_section(args: ControllerArgs, task: str):
    if getattr(args.task, "kind", None) != task:
        raise ValueError(f"this controller does the {task} task: it needs task: {{kind: {task}, ...}}")
    return args.task


def _formation(args: ControllerArgs):
    return _task_section(args, "formation")


def _coverage(args: ControllerArgs):
    return _task_section(args, "coverage")


@dataclass(frozen=True)
class ControllerKind:
    name: str
    summary: str
    batched: Callable[[ControllerArgs], Any]
    onboard: Callable[[ControllerArgs], Any] | None = None
    """None: not decentralized; the runtime runs it as one central process (``robot_agent.central``)."""
    options: tuple[str, ...] = field(default=())
    """Scenario keys of ``controller`` beyond ``kind`` that this kind reads."""
    task: str = "rendezvous"
    """The task it does (``swarm.core.tasks``); the scenario schema refuses it for another."""

    @property
    def central(self) -> bool:
        return self.onboard is None


CONTROLLER_KINDS: dict[str, ControllerKind] = {
    kind.name: kind
    for kind in (
        ControllerKind("gnn", "the learned GNN policy (controller.model)", _gnn, _onboard_gnn, ("model",)),
        ControllerKind(
            "local_consensus",
            "thesis eq. 3.1 on the robot's own graph",
            _local_consensus,
            _onboard_local_consensus,
            ("gain",),
        ),
        ControllerKind(
            "centralized",
            "thesis eq. 3.1 on the complete graph (the thesis's expert)",
            _centralized,
            None,
            ("gain",),
        ),
        ControllerKind(
            "mec_flood",
            "max-consensus flood of support points, full speed toward their MEC centre",
            _mec_flood,
            _onboard_mec_flood,
            ("directions", "reverse"),
        ),
        ControllerKind(
            "pack_flood",
            "gathering bodies: flood the starts, CAPT to a hexagonal packing at their MEC centre",
            _pack_flood,
            _onboard_pack_flood,
            ("spacing_m",),  # no `reverse`: HEADING_OUT picks each robot's law (it was accepted and unused)
        ),
        ControllerKind(
            "centralized_mec",
            "full speed toward the exact minimum enclosing circle's centre of the current positions",
            _centralized_mec,
            None,
            ("reverse",),
        ),
        ControllerKind(
            "capt",
            "formation: CAPT assignment of the start, time-synchronized drive to the slots (central)",
            _capt,
            None,
            ("reverse",),
            task="formation",
        ),
        ControllerKind(
            "capt_flood",
            "formation: flood the start positions, CAPT assignment of those known, full speed to the slot",
            _capt_flood,
            _onboard_capt_flood,
            ("reverse",),
            task="formation",
        ),
        ControllerKind(
            "capt_gnn",
            "formation: capt_flood's flood and provisional slot, a learned steering (controller.model)",
            _capt_gnn,
            _onboard_capt_gnn,
            ("model",),  # its learned steering has no `reverse` to set (it was accepted and unused)
            task="formation",
        ),
        ControllerKind(
            "lloyd",
            "coverage: every robot to its Voronoi cell's centroid among all robots (Lloyd; central)",
            _lloyd,
            None,
            ("reverse",),
            task="coverage",
        ),
        ControllerKind(
            "lloyd_local",
            "coverage: Lloyd over the heard neighbours' positions (Cortes et al. 2004)",
            _lloyd_local,
            _onboard_lloyd_local,
            ("reverse", "cell_radius_m", "step_fraction"),
            task="coverage",
        ),
        ControllerKind(
            "lloyd_flood",
            "coverage: flood every robot's freshest position, Lloyd over everyone known",
            _lloyd_flood,
            _onboard_lloyd_flood,
            ("reverse", "step_fraction"),
            task="coverage",
        ),
        ControllerKind(
            "lloyd_predict",
            "coverage: lloyd_flood with each robot's target flooded too, known robots placed where their "
            "targets take them (over at most horizon_ticks of an entry's age)",
            _lloyd_predict,
            _onboard_lloyd_predict,
            ("reverse", "horizon_ticks", "step_fraction"),
            task="coverage",
        ),
        ControllerKind(
            "lloyd_gnn",
            "coverage: lloyd_predict's flood and cells, a learned steering (controller.model)",
            _lloyd_gnn,
            _onboard_lloyd_gnn,
            ("model",),  # its learned steering has no `reverse` to set (it was accepted and unused)
            task="coverage",
        ),
    )
}


def controller_kind(name: str) -> ControllerKind:
    """The registry entry of ``name``; ValueError naming the known kinds otherwise."""
    try:
        return CONTROLLER_KINDS[name]
    except KeyError:
        raise ValueError(f"unknown controller kind {name!r} (known: {', '.join(CONTROLLER_KINDS)})") from None


def batched_controller(name: str, args: ControllerArgs):
    """The batched (kinematic-engine) controller of kind ``name``."""
    return controller_kind(name).batched(args)


def onboard_controller(name: str, args: ControllerArgs):
    """The onboard (one robot, numpy only) controller of kind ``name``; ValueError for a central kind."""
    kind = controller_kind(name)
    if kind.onboard is None:
        raise ValueError(f"controller {name!r} runs as one central process, not on board a robot")
    return kind.onboard(args)


def robot_controller(
    kind: str,
    robot: RobotParams,
    gain: float = 1.0,
    policy_bytes: bytes | None = None,
    robot_count: int = 0,
    control_period_s: float = 0.05,
    options: Mapping[str, Any] | None = None,
    task: Any = None,
    robot_id: int = 0,
):
    """The onboard controller of one robot (what a robot agent runs). ``gnn`` loads the policy
    file's bytes with the scenario's robot parameters; ``options`` is the scenario's ``controller``
    section (``mec_flood``: directions, reverse); ``task``: the scenario's task section (a task's
    controllers read it: ``capt_flood``) and ``robot_id`` the robot it runs on. Central kinds
    (``centralized``, ``centralized_mec``) are not onboard controllers: they run as one central process
    (``python -m robot_agent.central``); ValueError for them and for unknown kinds."""
    spec = {**(options or {}), "gain": gain}
    args = ControllerArgs.from_spec(
        spec,
        robot,
        control_period_s,
        robot_count=robot_count,
        policy=policy_bytes,
        task=task,
        robot_id=robot_id,
    )
    return onboard_controller(kind, args)
