"""Compiled batched forward of the max-flooding GNN (``gnn_flood``) inside the kinematic engine.

One numba pass over every robot of every environment does the whole tick of
``swarm.sim.policy.FloodPolicy``: memory update (max over own memory, own projection and heard
messages), smoothed minimax target (damped Newton steps), steering MLP, the robot's saturation and
the rotation to the world frame. Same arithmetic as the numpy reference ``FloodPolicy.raw_step`` (to rounding:
``tests/test_flood.py``); no fastmath, so the per-start results are those of the per-robot form.

What makes it fast (``bench/bench_gnn.py``), none of which changes a bit of the results:

- the max with a heard neighbour whose memory did not change at the last tick is skipped where
  the engine vouches that the robot already took it (``Skip``: ``swarm.sim.kinematic`` knows when
  the links change);
- the target is a function of the memory alone, so it is computed only when the memory changed,
  and not even then when a heard neighbour's last message carries this very memory (its target
  came with it): on a line or cycle that is about half of the changed memories during the flood;
- the steering features and the steering MLP run for a block of ``BLOCK`` robots at once, the
  innermost loop over the block's robots (SIMD lanes), every robot's sums in the order of a
  per-robot loop (no fastmath: no reassociation, no fused multiply-add);
- no integer division per robot, no allocation per tick beyond the outputs.

The kernel takes named arguments: three NamedTuples of arrays and numbers (``Weights``, ``Inputs``,
``Outputs``), which numba compiles as structs.

Threads are used for large batches only (``swarm.sim.kernels.PARALLEL_MIN_ROBOTS``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from swarm.sim import flood_readout, kernels

RELU, TANH = 0, 1
BLOCK = 128  # robots whose steering MLP runs together (SIMD lanes)


class Weights(NamedTuple):
    """A policy's weights and the readout's constants, as the kernel reads them (:func:`packed`)."""

    projections: np.ndarray  # (P, 2) flood directions, unnormalised
    norms: np.ndarray  # (P,) their lengths
    unit: np.ndarray  # (P, 2) their unit vectors
    tau_share: float  # the last Newton step's temperature, share of the width
    newton_steps: int
    steer_weights: np.ndarray  # layer l: [offset : offset + out * in], row-major (out, in)
    steer_biases: np.ndarray  # (L, widest), zero-padded
    steer_shapes: np.ndarray  # (L, 2) int64: (in, out) of layer l
    activation: int  # RELU or TANH
    output_scale_mps: float  # the steering's output speed (``flood_readout.steering_scales``)
    rho_cap_m: float  # its distance unit
    gate_m: float  # its gate distance, 0: no gate
    v_max_mps: float
    wheel_ratio: float  # half axle / offset: the saturation's |u_y| weight (swarm.core.robot.saturate_wheels)
    hessian_eps: float  # flood_readout.HESSIAN_EPS
    max_step: float  # flood_readout.MAX_STEP
    tau_start: float  # flood_readout.TAU_START
    rho_eps_m: float  # flood_readout.RHO_EPS_M


class Skip(NamedTuple):
    """Which heard messages a robot may leave out of its max (its result keeps every bit): robot i skips
    inbox column j where ``same_lists[b, i]`` and ``settled[b, j]`` and both messages are valid.

    ``settled (B, C)``: column j holds robot j's memory of the last call, which equals its memory of
    the call before (``Outputs.unchanged`` of the last call); ``same_lists (B, N)``: robot i's
    neighbour lists are those of the last call, and its own message (inbox column i) is its memory of
    that call. Then i already took the max with j's memory, and again changes nothing (max is
    idempotent). The engine that hands the outbox back as the next inbox knows both
    (``swarm.sim.kinematic.KinematicSim``); :func:`no_skip` for anyone else."""

    settled: np.ndarray  # (B, C) bool
    same_lists: np.ndarray  # (B, N) bool


class Inputs(NamedTuple):
    poses: np.ndarray  # (B, N, 3)
    inbox: np.ndarray  # (B, C, 2P + 3): columns 0..N-1 every robot's own last message
    neighbour_index: np.ndarray  # (B, N, S) int32 into the inbox's columns, -1 ends a list
    skip: Skip


class Outputs(NamedTuple):
    u_world: np.ndarray  # (B, N, 2)
    outbox: np.ndarray  # (B, N, 2P + 3)
    unchanged: np.ndarray  # (B, N) bool: the robot's memory is the one of its own last message


@numba.njit(cache=True)
def _target(values, p_count, weights, support, ux, uy, weight):
    """The smoothed minimax centre of one memory (``FloodPolicy.target``; same steps); ``support``,
    ``ux``, ``uy``, ``weight``: scratch of length 2P."""
    norms = weights.norms
    unit = weights.unit
    tau_share = weights.tau_share
    newton_steps = weights.newton_steps
    hessian_eps = weights.hessian_eps
    max_step = weights.max_step
    tau_start = weights.tau_start
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


def _flood_tick(weights, inputs, outputs, block_size, chunks):
    """One tick: ``weights`` (:class:`Weights`), ``inputs`` (:class:`Inputs`) -> ``outputs``
    (:class:`Outputs`, written in place); ``chunks`` tasks, each with its own scratch.

    Robots go in blocks of ``block_size`` (a run-time value, so that LLVM vectorizes the lane loops
    instead of unrolling them): per robot the memory, the target and the steering features;
    then the steering MLP for the whole block at once, the innermost loop over the block's robots
    (SIMD lanes; every robot's sums keep the order of a per-robot loop, so the bits do not change);
    then per robot the saturation and the rotation to the world frame."""
    poses = inputs.poses
    inbox = inputs.inbox
    neighbour_index = inputs.neighbour_index
    settled = inputs.skip.settled
    same_lists = inputs.skip.same_lists
    u_world = outputs.u_world
    outbox = outputs.outbox
    unchanged_now = outputs.unchanged
    projections = weights.projections
    steer_weights = weights.steer_weights
    steer_biases = weights.steer_biases
    steer_shapes = weights.steer_shapes
    activation = weights.activation
    output_scale = weights.output_scale_mps
    rho_cap = weights.rho_cap_m
    gate_m = weights.gate_m
    v_max = weights.v_max_mps
    ratio = weights.wheel_ratio
    rho_eps = weights.rho_eps_m
    batch, count = poses.shape[0], poses.shape[1]
    rows = batch * count
    slots = neighbour_index.shape[2]
    p_count = projections.shape[0]
    dim = 2 * p_count
    layers = steer_shapes.shape[0]
    widest = 3
    for layer in range(layers):
        widest = max(widest, steer_shapes[layer, 1])
    chunks = max(1, min(chunks, (rows + block_size - 1) // block_size))
    for chunk in numba.prange(chunks):
        values = np.empty(dim)
        support = np.empty(dim)
        ux_all = np.empty(dim)
        uy_all = np.empty(dim)
        weight = np.empty(dim)
        hidden_in = np.zeros((widest, block_size))  # layer input, one column per robot of the block
        hidden_out = np.zeros((widest, block_size))
        cos_block = np.zeros(block_size)  # zeros: the lanes past a partial block stay finite
        sin_block = np.zeros(block_size)
        dx_block = np.zeros(block_size)
        dy_block = np.zeros(block_size)
        gate_block = np.ones(block_size)
        heard_block = np.zeros(block_size, dtype=np.bool_)
        first = (chunk * rows) // chunks
        last = ((chunk + 1) * rows) // chunks
        for block in range(first, last, block_size):
            filled = min(block_size, last - block)
            env_first = block // count
            i_first = block % count
            env = env_first
            i = i_first - 1
            for lane in range(filled):  # robot i of environment env: row block + lane
                i += 1
                if i == count:
                    i = 0
                    env += 1
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
                heard = inbox[env, i, dim + 2] > 1.5  # flag 2: it has heard a neighbour at an earlier tick
                may_skip = own_valid and same_lists[env, i]
                for k in range(slots):
                    j = neighbour_index[env, i, k]
                    if j < 0:
                        break
                    heard = True
                    if may_skip and settled[env, j] and inbox[env, j, dim + 2] > 0.0:
                        continue  # already in this robot's own memory: the max with it changes nothing
                    for d in range(dim):
                        values[d] = max(values[d], inbox[env, j, d])
                changed = not own_valid
                for d in range(dim):
                    outbox[env, i, d] = values[d]
                    changed |= values[d] != inbox[env, i, d]  # no short cut: no branch
                unchanged_now[env, i] = not changed
                outbox[env, i, dim + 2] = 2.0 if heard else 1.0  # a real message; 2: has heard someone
                reused = not changed
                if reused:  # the same memory as last tick: the same target (a function of the memory alone)
                    cx = inbox[env, i, dim]
                    cy = inbox[env, i, dim + 1]
                else:  # a neighbour whose last memory is this one sent its target with it
                    for k in range(slots):
                        j = neighbour_index[env, i, k]
                        if j < 0:
                            break
                        if inbox[env, j, dim + 2] > 0.0:
                            same = True
                            for d in range(dim):
                                if values[d] != inbox[env, j, d]:
                                    same = False
                                    break
                            if same:
                                cx = inbox[env, j, dim]
                                cy = inbox[env, j, dim + 1]
                                reused = True
                                break
                if not reused:
                    cx, cy = _target(values, p_count, weights, support, ux_all, uy_all, weight)
                outbox[env, i, dim] = cx
                outbox[env, i, dim + 1] = cy
                heard_block[lane] = heard
                cos_block[lane] = math.cos(theta)
                sin_block[lane] = math.sin(theta)
                dx_block[lane] = cx - x
                dy_block[lane] = cy - y
            for lane in range(block_size):  # the steering features, all lanes together
                c = cos_block[lane]
                s = sin_block[lane]
                dx = dx_block[lane]
                dy = dy_block[lane]
                rx = c * dx + s * dy
                ry = -s * dx + c * dy
                rho = math.sqrt(rx * rx + ry * ry + rho_eps * rho_eps)
                hidden_in[0, lane] = rx / rho
                hidden_in[1, lane] = ry / rho
                hidden_in[2, lane] = min(rho / rho_cap, 1.0)
                gate_block[lane] = min(rho / gate_m, 1.0) if gate_m > 0.0 else 1.0
            offset = 0
            for layer in range(layers):  # the steering MLP, all lanes of the block together
                fan_in = steer_shapes[layer, 0]
                fan_out = steer_shapes[layer, 1]
                for o in range(fan_out):
                    bias = steer_biases[layer, o]
                    for lane in range(block_size):
                        hidden_out[o, lane] = bias
                # inputs outermost: every output's sum still runs over q = 0, 1, ... in order, and
                # consecutive updates of one output row are fan_out updates apart (no store-to-load stall)
                for q in range(fan_in):
                    for o in range(fan_out):
                        w = steer_weights[offset + o * fan_in + q]
                        for lane in range(block_size):
                            hidden_out[o, lane] += w * hidden_in[q, lane]
                for o in range(fan_out):  # the activation, into the next layer's input
                    if layer == layers - 1:
                        for lane in range(block_size):
                            hidden_in[o, lane] = hidden_out[o, lane]
                    elif activation == RELU:
                        for lane in range(block_size):
                            hidden_in[o, lane] = max(hidden_out[o, lane], 0.0)
                    else:
                        for lane in range(block_size):
                            hidden_in[o, lane] = math.tanh(hidden_out[o, lane])
                offset += fan_out * fan_in
            env = env_first
            i = i_first - 1
            for lane in range(filled):
                i += 1
                if i == count:
                    i = 0
                    env += 1
                if not heard_block[lane]:
                    u_world[env, i, 0] = 0.0
                    u_world[env, i, 1] = 0.0
                else:
                    ux = output_scale * hidden_in[0, lane] * gate_block[lane]
                    uy = output_scale * hidden_in[1, lane] * gate_block[lane]
                    # swarm.core.robot's saturation (half axle / offset = ratio / 1.0, the same bits)
                    largest = kernels.largest_wheel_speed_local(ux, uy, ratio, 1.0)
                    scale = kernels.wheel_speed_scale(largest, v_max)
                    ux *= scale
                    uy *= scale
                    c = cos_block[lane]
                    s = sin_block[lane]
                    u_world[env, i, 0] = c * ux - s * uy
                    u_world[env, i, 1] = s * ux + c * uy


# error_model="numpy": a float division by zero gives inf or nan as in numpy (``FloodPolicy``) instead of
# raising, which lets LLVM vectorize the lane loops that divide; no other result changes.
_serial, _parallel = kernels.jit_serial_and_parallel(_flood_tick, error_model="numpy")


def packed(policy) -> Weights:
    """The policy's weights as the kernel's :class:`Weights` (cached on the policy: they never change)."""
    cached = getattr(policy, "_kernel_weights", None)
    if cached is not None:
        return cached
    layers = policy._steer
    widest = max(weight.shape[0] for weight, _ in layers)
    biases = np.zeros((len(layers), widest))
    for index, (weight, bias) in enumerate(layers):
        biases[index, : weight.shape[0]] = 0.0 if bias is None else bias
    weights = Weights(
        projections=np.ascontiguousarray(policy.projections),
        norms=np.ascontiguousarray(policy._norms),
        unit=np.ascontiguousarray(policy._unit),
        tau_share=float(policy._tau_share),
        newton_steps=int(policy.model["newton_steps"]),
        steer_weights=np.ascontiguousarray(np.concatenate([weight.ravel() for weight, _ in layers])),
        steer_biases=biases,
        steer_shapes=np.array([[weight.shape[1], weight.shape[0]] for weight, _ in layers], dtype=np.int64),
        activation=RELU if policy.model["activation"] == "relu" else TANH,
        output_scale_mps=float(policy.steering_scales[2]),
        rho_cap_m=float(policy.steering_scales[0]),
        gate_m=float(policy.steering_scales[1]),
        v_max_mps=float(policy.robot.v_max_mps),
        wheel_ratio=float(policy.robot.half_axle_m / policy.robot.offset_m),
        hessian_eps=float(flood_readout.HESSIAN_EPS),
        max_step=float(flood_readout.MAX_STEP),
        tau_start=float(flood_readout.TAU_START),
        rho_eps_m=float(flood_readout.RHO_EPS_M),
    )
    policy._kernel_weights = weights
    return weights


def no_skip(batch: int, count: int, columns: int) -> Skip:
    """Nothing skipped: every heard message takes part in the max."""
    return Skip(np.zeros((batch, columns), dtype=np.bool_), np.zeros((batch, count), dtype=np.bool_))


def act(policy, poses: np.ndarray, inbox: np.ndarray, heard, skip: Skip | None = None) -> Outputs:
    """``FloodPolicy.act`` with what may be skipped (:class:`Skip`; None: nothing) -> :class:`Outputs`."""
    batch, count = poses.shape[:2]
    if inbox.ndim != 3 or inbox.shape[-1] != policy.message_dim or inbox.shape[:2] < (batch, count):
        raise ValueError(f"inbox of shape {inbox.shape}: expected (B, >= N, {policy.message_dim})")
    if heard.index.size and heard.index.max() >= inbox.shape[1]:
        raise ValueError("a neighbour index points past the inbox")
    columns = inbox.shape[1]
    if skip is None:
        skip = no_skip(batch, count, columns)
    elif skip.settled.shape != (batch, columns) or skip.same_lists.shape != (batch, count):
        raise ValueError(
            f"skip of shapes {skip.settled.shape}, {skip.same_lists.shape}: expected "
            f"({batch}, {columns}) (one per inbox column) and ({batch}, {count})"
        )
    outputs = Outputs(
        np.empty((batch, count, 2)),
        np.empty((batch, count, policy.message_dim)),
        np.empty((batch, count), dtype=np.bool_),
    )
    inputs = Inputs(
        np.ascontiguousarray(poses, dtype=np.float64),
        np.ascontiguousarray(inbox, dtype=np.float64),
        np.ascontiguousarray(heard.index),
        Skip(
            np.ascontiguousarray(skip.settled, dtype=np.bool_),
            np.ascontiguousarray(skip.same_lists, dtype=np.bool_),
        ),
    )
    parallel = batch * count >= kernels.PARALLEL_MIN_ROBOTS
    kernel = _parallel if parallel else _serial
    kernel(packed(policy), inputs, outputs, BLOCK, 4 * numba.get_num_threads() if parallel else 1)
    return outputs
