"""Compiled batched forward of the max-flooding GNN (``gnn_flood``) inside the kinematic engine.

One numba pass over every robot of every environment does the whole tick of
``swarm.sim.policy.FloodPolicy``: memory update (max over own memory, own projection and heard
messages), smoothed minimax target (damped Newton steps), steering MLP, the robot's saturation and
the rotation to the world frame. Same arithmetic as the numpy reference ``FloodPolicy.raw_step`` (to rounding:
``tests/test_flood.py``); no fastmath, so the per-start results are those of the per-robot form.

What makes it fast (``bench/bench_gnn.py``), none of which changes a bit of the results:

- the target is a function of the memory alone, so it is computed only when the memory changed,
  and not even then when a heard neighbour's last message carries this very memory (its target
  came with it): on a line or cycle that is about half of the changed memories during the flood;
- the steering features and the steering MLP run for a block of ``BLOCK`` robots at once, the
  innermost loop over the block's robots (SIMD lanes), every robot's sums in the order of a
  per-robot loop (no fastmath: no reassociation, no fused multiply-add);
- no integer division per robot, no allocation per tick beyond the two outputs, the inbox bound
  check once per neighbour-list object.

Threads are used for large batches only (``swarm.sim.kernels.PARALLEL_MIN_ROBOTS``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from swarm.sim import flood_readout, kernels

RELU, TANH = 0, 1
BLOCK = 128  # robots whose steering MLP runs together (SIMD lanes)


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
    block_size,
    chunks,
    unchanged_before,
    unchanged_now,
    u_world,
    outbox,
):
    """One tick: poses ``(B, N, 3)``, inbox ``(B, C, 2P + 3)`` (columns 0..N-1: every robot's own last
    message), neighbour lists ``(B, N, S)`` into the inbox's columns -> ``u_world (B, N, 2)``,
    ``outbox (B, N, 2P + 3)``. Steering layers flattened: layer l has weights
    ``steer_weights[offset : offset + out * in]`` (row-major ``(out, in)``),
    ``steer_shapes[l] = (in, out)``.

    Robots go in blocks of ``block_size`` (a run-time value, so that LLVM vectorizes the lane loops
    instead of unrolling them): per robot the memory, the target and the steering features;
    then the steering MLP for the whole block at once, the innermost loop over the block's robots
    (SIMD lanes; every robot's sums keep the order of a per-robot loop, so the bits do not change);
    then per robot the saturation and the rotation to the world frame."""
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
                for k in range(slots):
                    j = neighbour_index[env, i, k]
                    if j < 0:
                        break
                    heard = True
                    if own_valid and unchanged_before[env, j] and inbox[env, j, dim + 2] > 0.0:
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
                    ux = output_scale * hidden_in[0, lane]
                    uy = output_scale * hidden_in[1, lane]
                    biggest = abs(ux) + ratio * abs(uy)
                    scale = min(1.0, v_max / max(biggest, 1e-12))
                    ux *= scale
                    uy *= scale
                    c = cos_block[lane]
                    s = sin_block[lane]
                    u_world[env, i, 0] = c * ux - s * uy
                    u_world[env, i, 1] = s * ux + c * uy


# error_model="numpy": a float division by zero gives inf or nan as in numpy (``FloodPolicy``) instead of
# raising, which lets LLVM vectorize the lane loops that divide; no other result changes.
_serial, _parallel = kernels.jit_serial_and_parallel(_flood_tick, error_model="numpy")


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
    checked = getattr(policy, "_checked_links", None)  # a fixed graph: the same Links every tick
    if checked is None or checked[0] is not heard or checked[1] != inbox.shape[1]:
        if heard.index.size and heard.index.max() >= inbox.shape[1]:
            raise ValueError("a neighbour index points past the inbox")
        policy._checked_links = (heard, inbox.shape[1])
    u_world = np.empty((batch, count, 2))
    outbox = np.empty((batch, count, policy.message_dim))
    unchanged_now = np.empty((batch, count), dtype=np.bool_)
    unchanged_before = _unchanged_before(policy, inbox, heard, batch, count)
    parallel = batch * count >= kernels.PARALLEL_MIN_ROBOTS
    kernel = _parallel if parallel else _serial
    kernel(
        np.ascontiguousarray(poses, dtype=np.float64),
        np.ascontiguousarray(inbox, dtype=np.float64),
        np.ascontiguousarray(heard.index),
        *packed(policy),
        flood_readout.HESSIAN_EPS,
        flood_readout.MAX_STEP,
        flood_readout.TAU_START,
        flood_readout.RHO_EPS_M,
        BLOCK,
        4 * numba.get_num_threads() if parallel else 1,  # chunks, each with its own scratch
        unchanged_before,
        unchanged_now,
        u_world,
        outbox,
    )
    policy._last_call = (outbox, heard, unchanged_now)
    return u_world, outbox


def _unchanged_before(policy, inbox: np.ndarray, heard, batch: int, count: int) -> np.ndarray:
    """Per robot ``(B, N)``: may its message in ``inbox`` be skipped by the neighbours' max?

    True only where the last call of this policy returned ``inbox`` itself as its outbox, over the same
    neighbour lists ``heard`` (a fixed graph, no link faults: ``KinematicSim`` passes the outbox back as
    the next inbox), and robot j's memory did not change in that call. Then every neighbour i with a
    valid own message already took the max with j's previous memory, which equals j's current one, and
    the max with it again is the identity (max is idempotent): skipped, the result keeps every bit. The
    kernel also requires both messages valid, which covers an inbox whose rows were zeroed in place
    (an environment reset); any other edit of a returned outbox before passing it back is not supported.
    """
    last = getattr(policy, "_last_call", None)
    if last is not None and last[0] is inbox and last[1] is heard and inbox.shape[1] == count:
        return last[2]
    return np.zeros((batch, count), dtype=np.bool_)
