"""The recurrent max-flooding GNN (kind ``gnn_flood``): a learned decentralized rendezvous controller.

Every robot i keeps a memory ``h_i`` of ``2P`` numbers, which is also its message. With learned
projection vectors ``W_p`` (P of them, world frame, metres^-1 ... any length) and ``x_i(k)`` the
robot's axle position at tick k::

    h_i(k) = max( h_i(k-1),  [W x_i(k), -W x_i(k)],  max_{j heard at k} h_j(k-1) )     (elementwise)

(``max`` over heard neighbours is PyG's ``aggr="max"``: permutation invariant and idempotent, so a
lost or repeated message only delays the flood, never biases it). Once information from every
robot has arrived, ``h_p^+ = max_j <x_j, W_p>`` and ``h_p^- = -min_j <x_j, W_p>`` over every
position any robot has had: the support function of the swarm's extent along the learned
directions, identical at every robot. Readout (robot i, tick k)::

    u_q, s_q: the 2P unit directions [W_p / |W_p|, -W_p / |W_p|] and their support values in metres
              [h_p^+ / |W_p|, h_p^- / |W_p|];  w = max_p (h_p^+ + h_p^-) / |W_p|  (the widest extent)
    c = argmin_c  tau log sum_q exp((s_q - <c, u_q>) / tau),   tau = exp(log_tau) w       learned tau
    r = R(theta_i)^T (c - x_i),   rho = |r|
    u_local = output_scale * MLP( r / rho, min(rho / rho_cap, 1) )         robot frame, "metric"
    u_local = v_max MLP( r / rho, min(rho_n, 1) ) min(rho_n, 1),   rho_n = rho / (v_max T)     "scaled"

Two steering forms. ``metric`` (the files up to ``gnn_flood.npz``): the cap ``rho_cap`` and the output
speed are metres and m/s fixed at training, so a robot with another v_max, period or success threshold
meets a law fitted elsewhere. ``scaled`` (``gnn_default.npz`` from 2026-12-02): distances in units of
``v_max T`` of the robot that runs it and speeds in units of its ``v_max``, which is exactly the scale
of the expert's law ``u = (c - x) min(v_max / |c - x|, 1 / T)`` (``swarm.core.experts``): that law is
``v_max min(rho_n, 1) d(r / rho)`` with ``d`` the direction (reflected when the robot reverses), so the
MLP is left the direction and the wheel saturation's shape, and the gate ``min(rho_n, 1)`` makes the
command vanish on the target at every scale (``metric`` steering never reaches zero there: its swarm
ends about 0.1 m across). The MLP imitates the expert's closed form, so learning adds nothing here
beyond fitting it (``bench/results/gnn_scale.md``: within 2% of ``mec_flood`` at every scale measured).

``s_q - <c, u_q>`` is how far the swarm reaches beyond c along u_q; over all directions its max is
the radius of the smallest circle around c that holds the swarm, so the minimiser is the minimum
enclosing circle's centre (of the polygon the support lines bound; a soft max with temperature
tau). It is computed by ``newton_steps`` damped Newton steps (each moves c by at most half the
width) from the least-squares centre of the midpoints, the temperature falling geometrically from
0.2 w to the learned tau (continuation), unrolled, so training differentiates through it. With
P = 12 directions the result is within 1% of the radius of the exact centre for most swarms.
The robot then saturates ``u_local``
(``swarm.sim.features.saturate_local_velocity``) and rotates it to the world. A robot holds still until
it has heard a neighbour once (tick 0 for everybody; a robot cut off from the start); from then on
it steers toward its memory's target in every tick, heard or not (a tick without messages leaves
the memory as it was, so the target is still the best it knows; as ``mec_flood``).

Inductive biases built in (and what is learned):

- information: the only thing flooded is the max and min of learned linear projections of
  positions. That is enough to represent the extent of the swarm (the support function, whose
  exact form for all directions determines the convex hull), it floods one hop per tick exactly
  like ``mec_flood``, and it is idempotent. The projections are in the world frame, which a robot
  can compute because it knows its own absolute pose; a max over robot-frame quantities would have
  no common meaning. What the projection vectors are is learned (initialised evenly spaced).
- the target is translation-equivariant (shifting every position shifts ``c`` by the same) and
  scale-equivariant (tau, the step limit and the regularisation scale with the width), so it
  transfers from the N <= 12 of training to any swarm size. That it is a minimum-enclosing-circle
  centre of the flooded extent is built in (the expert's target); the directions and the
  temperature are learned.
- the steering is rotation-equivariant: it sees the target only in the robot's own frame, as
  a direction and a capped distance, and the speed/turn/reverse law is a learned MLP; scaled
  steering is also scale-equivariant (above), with the near-target ramp built in.
- nothing about the graph is assumed: the memory only grows, so any connected graph (fixed, changing,
  lossy) eventually gives every robot the same target.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
from torch import nn

from swarm.core.robot import RobotParams
from swarm.learn.models.base import linears, saturate
from swarm.sim.flood_readout import (
    HESSIAN_EPS,
    MAX_STEP,
    METRIC,
    RHO_EPS_M,
    STEERING_FORMS,
    TAU_START,
    steering_scales,
)
from swarm.sim.policy import save_policy

KIND = "gnn_flood"


def tau_share_at(step: int, steps: int, final_share):
    """Temperature (share of the width) of Newton step ``step``: from ``TAU_START`` down to the learned
    final share, geometrically (continuation: a large temperature first, so the steps converge)."""
    return TAU_START * (final_share / TAU_START) ** (step / max(steps - 1, 1))


def _activation(name: str):
    return torch.relu if name == "relu" else torch.tanh


class FloodGNN(nn.Module):
    """Torch form of ``gnn_flood`` (module docstring); ``swarm.sim.policy.FloodPolicy`` is its numpy form."""

    kind = KIND

    def __init__(
        self,
        directions: int = 12,
        steer_hidden: tuple[int, ...] | list[int] = (16, 16),
        newton_steps: int = 12,
        tau_share: float = 0.003,
        rho_cap_m: float = 0.5,
        output_scale_mps: float = 2.0,
        activation: str = "relu",
        steering: str = METRIC,
        v_max_mps: float = 0.5,
        control_period_s: float = 0.05,
    ):
        super().__init__()
        if steering not in STEERING_FORMS:
            raise ValueError(f"steering {steering!r}: one of {STEERING_FORMS}")
        self.steering = steering
        # the robot and period it trains at: the scaled steering's units (not part of the file's model)
        self.v_max_mps = float(v_max_mps)
        self.control_period_s = float(control_period_s)
        self.directions = int(directions)
        self.steer_hidden = [int(width) for width in steer_hidden]
        self.newton_steps = int(newton_steps)
        self.rho_cap_m = float(rho_cap_m)
        self.output_scale_mps = float(output_scale_mps)
        self.activation = activation
        angles = torch.arange(self.directions, dtype=torch.float32) * (math.pi / self.directions)
        self.projections = nn.Parameter(torch.stack([torch.cos(angles), torch.sin(angles)], dim=-1))  # (P, 2)
        self.log_tau = nn.Parameter(torch.tensor(math.log(tau_share)))
        self.steer = linears([3, *self.steer_hidden, 2])

    @property
    def message_dim(self) -> int:
        return 2 * self.directions

    def architecture(self) -> dict:
        return {
            "kind": self.kind,
            "activation": self.activation,
            "directions": self.directions,
            "steer_hidden": self.steer_hidden,
            "newton_steps": self.newton_steps,
            "rho_cap_m": self.rho_cap_m,
            **({"steering": self.steering} if self.steering != METRIC else {}),
        }

    def config(self) -> dict:
        return {"model": self.architecture(), "output_scale_mps": self.output_scale_mps}

    # -- the recurrence ----------------------------------------------------------------------------

    def own_values(self, axle_m: torch.Tensor) -> torch.Tensor:
        """``[W x, -W x]`` ``(..., 2P)`` for axle positions ``(..., 2)``."""
        projected = axle_m @ self.projections.T
        return torch.cat([projected, -projected], dim=-1)

    def update(
        self, memory: torch.Tensor | None, axle_m: torch.Tensor, inbox: torch.Tensor, heard: torch.Tensor
    ) -> torch.Tensor:
        """New memory ``(B, N, 2P)``: own memory (None at a robot's first tick), own projection, and the
        max over heard neighbours' last messages ``inbox (B, N, 2P)``; ``heard (B, N, N)`` bool."""
        values = self.own_values(axle_m)
        if memory is not None:
            values = torch.maximum(values, memory)
        if heard.any():
            masked = torch.where(
                heard[..., None], inbox[:, None, :, :], torch.full_like(inbox[:, None], -torch.inf)
            )
            values = torch.maximum(values, masked.amax(dim=2))
        return values

    def target(self, memory: torch.Tensor) -> torch.Tensor:
        """World-frame target ``(..., 2)`` from the memory ``(..., 2P)``: the smoothed minimax centre
        (module docstring), ``newton_steps`` damped Newton steps from the least-squares centre."""
        count = self.directions
        norms = torch.linalg.vector_norm(self.projections, dim=-1)
        unit = self.projections / norms[:, None]
        upper, lower = memory[..., :count] / norms, memory[..., count:] / norms
        support = torch.cat([upper, lower], dim=-1)  # h(u) for the 2P directions u = [unit, -unit]
        directions = torch.cat([unit, -unit], dim=0)
        width = (upper + lower).amax(dim=-1) + 1e-9
        share = torch.exp(self.log_tau)
        gram = unit.T @ unit  # least squares: sum_p u_p u_p^T c = sum_p mid_p u_p
        middle = 0.5 * (upper - lower)
        bx, by = (middle * unit[:, 0]).sum(-1), (middle * unit[:, 1]).sum(-1)
        det = gram[0, 0] * gram[1, 1] - gram[0, 1] ** 2
        cx = (gram[1, 1] * bx - gram[0, 1] * by) / det
        cy = (gram[0, 0] * by - gram[0, 1] * bx) / det
        ux, uy = directions[:, 0], directions[:, 1]
        for step in range(self.newton_steps):
            tau = width * tau_share_at(step, self.newton_steps, share)
            slack = (support - cx[..., None] * ux - cy[..., None] * uy) / tau[..., None]
            weight = torch.softmax(slack, dim=-1)
            gx, gy = (weight * ux).sum(-1), (weight * uy).sum(-1)
            hxx = ((weight * ux * ux).sum(-1) - gx * gx + HESSIAN_EPS) / tau
            hxy = ((weight * ux * uy).sum(-1) - gx * gy) / tau
            hyy = ((weight * uy * uy).sum(-1) - gy * gy + HESSIAN_EPS) / tau
            det = hxx * hyy - hxy * hxy
            dx, dy = (hyy * gx - hxy * gy) / det, (hxx * gy - hxy * gx) / det
            length = torch.sqrt(dx * dx + dy * dy + 1e-30)
            damp = torch.clamp(MAX_STEP * width / length, max=1.0)
            cx, cy = cx + damp * dx, cy + damp * dy
        return torch.stack([cx, cy], dim=-1)

    @staticmethod
    def _mlp(layers: nn.ModuleList, x: torch.Tensor, activation) -> torch.Tensor:
        for index, layer in enumerate(layers):
            x = layer(x)
            if index < len(layers) - 1:
                x = activation(x)
        return x

    def steer_local(self, poses: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """Raw (unsaturated) robot-frame point velocity ``(..., 2)`` toward the world ``target``."""
        c, s = torch.cos(poses[..., 2]), torch.sin(poses[..., 2])
        dx, dy = target[..., 0] - poses[..., 0], target[..., 1] - poses[..., 1]
        rx, ry = c * dx + s * dy, -s * dx + c * dy
        rho = torch.sqrt(rx * rx + ry * ry + RHO_EPS_M**2)
        rho_unit_m, gate_m, output_mps = steering_scales(
            self.steering, self.rho_cap_m, self.output_scale_mps, self.v_max_mps, self.control_period_s
        )
        features = torch.stack([rx / rho, ry / rho, torch.clamp(rho / rho_unit_m, max=1.0)], dim=-1)
        u_local = output_mps * self._mlp(self.steer, features, _activation(self.activation))
        if gate_m > 0.0:
            u_local = u_local * torch.clamp(rho / gate_m, max=1.0)[..., None]
        return u_local

    def step(
        self,
        poses: torch.Tensor,
        memory: torch.Tensor | None,
        inbox: torch.Tensor,
        heard: torch.Tensor,
        has_heard: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One tick for ``(B, N, 3)`` poses: raw robot-frame ``u_local`` (zero where a robot has never
        heard anybody, this tick included), the new memory (= the message) and the new ``has_heard``
        ``(B, N)`` bool (``has_heard`` in: whether it heard someone at an earlier tick; None: nobody)."""
        memory = self.update(memory, poses[..., :2], inbox, heard)
        u_local = self.steer_local(poses, self.target(memory))
        moving = heard.any(dim=-1)
        if has_heard is not None:
            moving = moving | has_heard
        return torch.where(moving[..., None], u_local, torch.zeros_like(u_local)), memory, moving

    def saturated(self, u_local: torch.Tensor, robot: RobotParams) -> torch.Tensor:
        return saturate(u_local, robot)

    def export(self, path: str | Path, robot: RobotParams, training: dict | None = None) -> Path:
        """Write the one-file policy that ``swarm.sim.policy`` runs with numpy alone."""
        arrays = {name: value.detach().cpu().numpy() for name, value in self.state_dict().items()}
        metadata = {**self.config(), "robot": robot.model_dump(), "training": training or {}}
        return save_policy(path, metadata, arrays)


def build_flood(config: dict, v_max_mps: float = 0.5, control_period_s: float = 0.05) -> FloodGNN:
    """The model of a policy file's ``model`` section (``v_max_mps`` and ``control_period_s``: the
    robot and period it trains at, which scaled steering measures in)."""
    architecture = dict(config["model"])
    architecture.pop("kind")
    return FloodGNN(
        **architecture,
        output_scale_mps=config.get("output_scale_mps", 2.0),
        v_max_mps=v_max_mps,
        control_period_s=control_period_s,
    )
