"""Compiled batched forward of the max-flooding GNN (``gnn_flood``) inside the kinematic engine.

One numba pass over every robot of every environment does the whole tick of
``swarm.policy.FloodPolicy``: memory update (max over own memory, own projection and heard
messages), smoothed minimax target (damped Newton steps), steering MLP, the robot's saturation and
the rotation to the world frame. Same arithmetic as the numpy reference ``FloodPolicy.raw_step`` (to rounding:
``tests/test_flood.py``); no fastmath, so the per-start results are those of the per-robot form.
Threads are used for large batches only (``swarm.kernels.PARALLEL_MIN_ROBOTS``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np

from swarm import flood_readout, kernels

RELU, TANH = 0, 1
CHUNKS = 64  # environments are split into this many chunks (threads), each with its own scratch


@numba.njit(cache=True)
def _target(
    values,
    p_count,
    norms,
    unit,
    tau_share,
    newton_steps,
    hessian_eps,
    max_step,
    tau_start,
    support,
    ux,
    uy,
    weight,
):
    """The smoothed minimax centre of one memory (``FloodPolicy.target``; same steps)."""
    width = -np.inf
    bx = 0.0
    by = 0.0
    for p in range(p_count):
        upper = values[p] / norms[p]
        lower = values[p_count + p] / norms[p]
        support[p] = upper
        support[p_count + p] = lower
        ux[p] = unit[p, 0]
        uy[p] = unit[p, 1]
        ux[p_count + p] = -unit[p, 0]
        uy[p_count + p] = -unit[p, 1]
        width = max(width, upper + lower)
        middle = 0.5 * (upper - lower)
        bx += middle * unit[p, 0]
        by += middle * unit[p, 1]
    width += 1e-9
    gxx = 0.0
    gxy = 0.0
    gyy = 0.0
    for p in range(p_count):
        gxx += unit[p, 0] * unit[p, 0]
        gxy += unit[p, 0] * unit[p, 1]
        gyy += unit[p, 1] * unit[p, 1]
    det = gxx * gyy - gxy * gxy
    cx = (gyy * bx - gxy * by) / det
    cy = (gxx * by - gxy * bx) / det
    directions = 2 * p_count
    for step in range(newton_steps):
        tau = width * (tau_start * (tau_share / tau_start) ** (step / max(newton_steps - 1, 1)))
        top = -np.inf
        for q in range(directions):
            weight[q] = (support[q] - cx * ux[q] - cy * uy[q]) / tau
            top = max(top, weight[q])
        total = 0.0
        for q in range(directions):
            weight[q] = math.exp(weight[q] - top)
            total += weight[q]
        gx = 0.0
        gy = 0.0
        sxx = 0.0
        sxy = 0.0
        syy = 0.0
        for q in range(directions):
            w = weight[q] / total
            gx += w * ux[q]
            gy += w * uy[q]
            sxx += w * ux[q] * ux[q]
            sxy += w * ux[q] * uy[q]
            syy += w * uy[q] * uy[q]
        hxx = (sxx - gx * gx + hessian_eps) / tau
        hxy = (sxy - gx * gy) / tau
        hyy = (syy - gy * gy + hessian_eps) / tau
        det = hxx * hyy - hxy * hxy
        dx = (hyy * gx - hxy * gy) / det
        dy = (hxx * gy - hxy * gx) / det
        length = math.sqrt(dx * dx + dy * dy + 1e-30)
        damp = min(max_step * width / length, 1.0)
        cx += damp * dx
        cy += damp * dy
    return cx, cy


def _flood_tick(
    poses,
    inbox,
    neighbour_index,
    projections,
    norms,
    unit,
    tau_share,
    newton_steps,
    steer_weights,
    steer_biases,
    steer_shapes,
    activation,
    output_scale,
    rho_cap,
    v_max,
    ratio,
    hessian_eps,
    max_step,
    tau_start,
    rho_eps,
    u_world,
    outbox,
):
    """One tick: poses ``(B, N, 3)``, inbox ``(B, C, 2P + 3)`` (columns 0..N-1: every robot's own last
    message), neighbour lists ``(B, N, S)`` into the inbox's columns -> ``u_world (B, N, 2)``,
    ``outbox (B, N, 2P + 3)``. Steering layers flattened: layer l has weights
    ``steer_weights[offset : offset + out * in]`` (row-major ``(out, in)``),
    ``steer_shapes[l] = (in, out)``."""
    batch, count = poses.shape[0], poses.shape[1]
    slots = neighbour_index.shape[2]
    p_count = projections.shape[0]
    dim = 2 * p_count
    layers = steer_shapes.shape[0]
    widest = 3
    for layer in range(layers):
        widest = max(widest, steer_shapes[layer, 1])
    chunks = min(batch, CHUNKS)
    for chunk in numba.prange(chunks):  # scratch arrays once per chunk of environments
        values = np.empty(dim)
        support = np.empty(dim)
        ux_all = np.empty(dim)
        uy_all = np.empty(dim)
        weight = np.empty(dim)
        buffer_a = np.empty(widest)
        buffer_b = np.empty(widest)
        for row in range((chunk * batch) // chunks * count, ((chunk + 1) * batch) // chunks * count):
            env = row // count
            i = row % count
            x = poses[env, i, 0]
            y = poses[env, i, 1]
            theta = poses[env, i, 2]
            own_valid = inbox[env, i, dim + 2] > 0.0
            for p in range(p_count):
                projected = x * projections[p, 0] + y * projections[p, 1]
                hi = projected
                lo = -projected
                if own_valid:
                    hi = max(hi, inbox[env, i, p])
                    lo = max(lo, inbox[env, i, p_count + p])
                values[p] = hi
                values[p_count + p] = lo
            heard = False
            for k in range(slots):
                j = neighbour_index[env, i, k]
                if j < 0:
                    break
                heard = True
                for d in range(dim):
                    values[d] = max(values[d], inbox[env, j, d])
            changed = not own_valid
            for d in range(dim):
                outbox[env, i, d] = values[d]
                changed = changed or values[d] != inbox[env, i, d]
            outbox[env, i, dim + 2] = 1.0
            if changed:
                cx, cy = _target(
                    values,
                    p_count,
                    norms,
                    unit,
                    tau_share,
                    newton_steps,
                    hessian_eps,
                    max_step,
                    tau_start,
                    support,
                    ux_all,
                    uy_all,
                    weight,
                )
            else:  # the same memory as last tick: the same target (a function of the memory alone)
                cx = inbox[env, i, dim]
                cy = inbox[env, i, dim + 1]
            outbox[env, i, dim] = cx
            outbox[env, i, dim + 1] = cy
            if not heard:
                u_world[env, i, 0] = 0.0
                u_world[env, i, 1] = 0.0
                continue
            c = math.cos(theta)
            s = math.sin(theta)
            dx = cx - x
            dy = cy - y
            rx = c * dx + s * dy
            ry = -s * dx + c * dy
            rho = math.sqrt(rx * rx + ry * ry + rho_eps * rho_eps)
            buffer_a[0] = rx / rho
            buffer_a[1] = ry / rho
            buffer_a[2] = min(rho / rho_cap, 1.0)
            offset = 0
            for layer in range(layers):
                fan_in = steer_shapes[layer, 0]
                fan_out = steer_shapes[layer, 1]
                for o in range(fan_out):
                    z = steer_biases[layer, o]
                    base = offset + o * fan_in
                    for q in range(fan_in):
                        z += steer_weights[base + q] * buffer_a[q]
                    if layer < layers - 1:
                        z = max(z, 0.0) if activation == RELU else math.tanh(z)
                    buffer_b[o] = z
                offset += fan_out * fan_in
                for o in range(fan_out):
                    buffer_a[o] = buffer_b[o]
            ux = output_scale * buffer_a[0]
            uy = output_scale * buffer_a[1]
            biggest = abs(ux) + ratio * abs(uy)
            scale = min(1.0, v_max / max(biggest, 1e-12))
            ux *= scale
            uy *= scale
            u_world[env, i, 0] = c * ux - s * uy
            u_world[env, i, 1] = s * ux + c * uy


# Typed as plain callables: numba's Dispatcher declares a narrower __call__ than the compiled kernel.
_serial: Callable[..., None] = numba.njit(cache=True)(_flood_tick)
_parallel: Callable[..., None] = numba.njit(cache=True, parallel=True)(_flood_tick)


def packed(policy) -> tuple:
    """The policy's weights as the kernel's arguments (cached on the policy)."""
    cached = getattr(policy, "_kernel_arguments", None)
    if cached is not None:
        return cached
    layers = policy._steer
    widest = max(weight.shape[0] for weight, _ in layers)
    biases = np.zeros((len(layers), widest))
    for index, (weight, bias) in enumerate(layers):
        biases[index, : weight.shape[0]] = 0.0 if bias is None else bias
    arguments = (
        np.ascontiguousarray(policy.projections),
        np.ascontiguousarray(policy._norms),
        np.ascontiguousarray(policy._unit),
        policy._tau_share,
        int(policy.model["newton_steps"]),
        np.ascontiguousarray(np.concatenate([weight.ravel() for weight, _ in layers])),
        biases,
        np.array([[weight.shape[1], weight.shape[0]] for weight, _ in layers], dtype=np.int64),
        RELU if policy.model["activation"] == "relu" else TANH,
        policy.output_scale_mps,
        float(policy.model["rho_cap_m"]),
        policy.robot.v_max_mps,
        policy.robot.half_axle_m / policy.robot.offset_m,
    )
    policy._kernel_arguments = arguments
    return arguments


def act(policy, poses: np.ndarray, inbox: np.ndarray, heard) -> tuple[np.ndarray, np.ndarray]:
    """``FloodPolicy.act``: ``(u_world (B, N, 2), outbox (B, N, 2P + 1))``."""

    batch, count = poses.shape[:2]
    if inbox.ndim != 3 or inbox.shape[-1] != policy.message_dim or inbox.shape[:2] < (batch, count):
        raise ValueError(f"inbox of shape {inbox.shape}: expected (B, >= N, {policy.message_dim})")
    if heard.index.size and heard.index.max() >= inbox.shape[1]:
        raise ValueError("a neighbour index points past the inbox")
    u_world = np.empty((batch, count, 2))
    outbox = np.empty((batch, count, policy.message_dim))
    kernel = _parallel if batch * count >= kernels.PARALLEL_MIN_ROBOTS else _serial
    kernel(
        np.ascontiguousarray(poses, dtype=np.float64),
        np.ascontiguousarray(inbox, dtype=np.float64),
        np.ascontiguousarray(heard.index),
        *packed(policy),
        flood_readout.HESSIAN_EPS,
        flood_readout.MAX_STEP,
        flood_readout.TAU_START,
        flood_readout.RHO_EPS_M,
        u_world,
        outbox,
    )
    return u_world, outbox
