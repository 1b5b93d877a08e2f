"""The learned formation controller ``capt_gnn``: ``capt_flood``'s messages, a learned steering (numpy).

Information and aggregation are ``capt_flood``'s (``swarm.sim.formation_controllers``): every robot
floods the initial axle positions it knows (``N x (known, x, y)``, a union: the max-aggregation GNN
layer of ``capt_flood``, idempotent under loss and repetition) and, each time that set grows, computes
the CAPT assignment of the robots it knows to all N slots. From that a robot has, in its own frame:

- ``r``: the vector from its axle to its provisional slot; ``rho = |r|``, ``rho_n = rho / (v_max T)``;
- ``sync = d_i0 / D_0`` (at most 1): its own start-to-slot distance over the largest among the robots
  it knows, the time-synchronization factor of the expert (in the holonomic limit ``d_i(t) / D(t)``
  is constant, so the robot can compute the expert's speed ratio from the starts alone);
- ``known``: the fraction of the N robots it knows (1 once the flood has reached it from everyone).

Features ``f = (r_x / rho, r_y / rho, min(rho_n, 1), sync, known)`` and a tanh MLP ``g`` (2 hidden
layers, 3 outputs ``(a, b, c)``) give the robot-frame point velocity in polar form::

    u_local = v_max min(rho_n, 1) clip(c, 0, 1) (a, b) / |(a, b)|                          (1)

The gate ``min(rho_n, 1)`` makes the command vanish on the slot at every scale (the expert's law
``u = r min(v_max q / rho, 1 / T)`` has the same factor). ``(a, b)`` is the direction, reversal
included (``swarm.core.experts.drive_toward_velocity`` steers the axle backward when the slot is
behind), and ``clip(c, 0, 1)`` the speed: the expert's ``q = d_i / D`` where the robot knows everyone
(clipped, not squashed: a sigmoid fitted to the bottleneck robot's full speed stays under it, 3.5%
slower on the complete graph of 100 where everyone is known at once).
Where it does not yet, imitation (``swarm.learn.train.formation``) fits the expert's speed and its
direction separately: a Cartesian output fitted to commands toward a slot the robot cannot know yet
is their average, shorter than any of them (measured: 3-5% slower than ``capt_flood`` at N <= 12).
The robot's wheels saturate (1) as every controller's do.

The MLP, eq. (1) and the policy file (format ``formation_gnn/1``) are ``swarm.sim.steering_mlp``'s,
shared with the coverage controller ``lloyd_gnn``. The batched form
(``swarm.sim.formation_controllers.CaptGnn``) and the per-robot one (:class:`OnboardCaptGnn`, here:
numpy only, what the agents import) share :func:`local_command`.
"""

from __future__ import annotations

import numpy as np

from swarm.core.robot import RobotParams
from swarm.core.tasks.formation import FormationSection
from swarm.sim.formation_onboard import OnboardCaptFlood
from swarm.sim.steering_mlp import (
    PolicyFileError,
    SteeringMlp,
    local_command,
    target_features,
    to_world,
)

FEATURES = ("dir_x", "dir_y", "near", "sync", "known")
DEFAULT_MODEL_NAME = "formation/capt_gnn.npz"
"""The shipped policy, below ``<project root>/models`` (``swarm train --algo formation``; its own folder:
``models/*.npz`` are rendezvous policies)."""

FormationPolicyError = PolicyFileError


class FormationGnnWeights(SteeringMlp):
    """The MLP ``g`` of eq. (1) for ``capt_gnn`` (``swarm.sim.steering_mlp``)."""

    FORMAT = "formation_gnn/1"
    FEATURES = FEATURES
    KIND = "capt_gnn"


FORMAT = FormationGnnWeights.FORMAT


def steering_features(
    poses: np.ndarray,
    targets: np.ndarray,
    sync: np.ndarray,
    known: np.ndarray,
    robot: RobotParams,
    control_period_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (1)'s features ``(..., 5)`` and gate ``min(rho_n, 1)`` ``(...)`` from poses ``(..., 3)``, the
    provisional slots ``(..., 2)`` and the ``sync`` and ``known`` fractions ``(...)``."""
    direction, gate = target_features(poses, targets, robot, control_period_s)
    return np.concatenate([direction, np.stack([sync, known], axis=-1)], axis=-1), gate


class OnboardCaptGnn(OnboardCaptFlood):
    """``capt_gnn`` for robot ``robot_id`` (``swarm.sim.onboard``'s protocol; numpy only)."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: FormationSection,
        robot_count: int,
        robot_id: int,
        weights: FormationGnnWeights,
        reverse: bool = True,
    ):
        super().__init__(robot, control_period_s, section, robot_count, robot_id, reverse)
        self.weights = weights

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        pose = np.asarray(pose, dtype=np.float64)
        memory = self.update_target(pose, neighbour_messages)
        features, gate = steering_features(
            pose,
            self._target,
            np.float64(self._sync),
            np.float64(self._known_fraction),
            self.robot,
            self.control_period_s,
        )
        u_local = local_command(self.weights, features, gate, self.robot.v_max_mps)
        return to_world(pose, u_local), memory.reshape(-1).copy()
