"""Numerics of the flooding GNN's readout, shared by its three forms.

The torch model (``swarm.learn.models.flood``), the numpy policy (``swarm.sim.policy``) and the compiled
batched kernel (``swarm.sim.flood_kernel``) find the minimum-enclosing-circle centre of the flooded
extent with the same damped Newton steps on a smoothed minimax; these constants are that solver's.
This module imports nothing, so the torch-free agent and the numba kernel can both read it.
"""

HESSIAN_EPS = 1e-4  # regularises the Newton step's 2 x 2 solve (relative: the Hessian is O(1 / tau))
MAX_STEP = 0.5  # a Newton step moves the centre by at most this share of the swarm's width
TAU_START = 0.2  # temperature of the first Newton step, share of the width
RHO_EPS_M = 1e-6  # regularises the target direction of a robot on its target

METRIC = "metric"  # steering features and output in metres and m/s, fixed when the model was trained
SCALED = "scaled"  # in units of the running robot's v_max T (distances) and v_max (speeds)
STEERING_FORMS = (METRIC, SCALED)


def steering_scales(
    form: str, rho_cap_m: float, output_scale_mps: float, v_max_mps: float, control_period_s: float
) -> tuple[float, float, float]:
    """``(rho_unit_m, gate_m, output_mps)`` of the steering (``swarm.learn.models.flood``): the distance
    feature is ``min(rho / rho_unit, 1)``, the command ``output * MLP(...) * min(rho / gate, 1)``
    (no gate where ``gate_m`` is 0).

    ``metric``: the file's cap and output speed, no gate. ``scaled``: every scale from the robot that
    runs it, ``rho_unit = gate = v_max T`` and ``output = v_max``. The expert's steering law
    ``u = (c - x) min(v_max / |c - x|, 1 / T)`` (``swarm.core.experts.drive_toward_velocity``), and the
    wheel saturation, are exactly ``v_max min(rho_n, 1) d(direction)`` (``rho_n = |c - x| / (v_max T)``,
    ``d`` a unit vector, reflected when the robot reverses) before the robot's saturation, so a scaled MLP
    fitted at one robot scale is the same law at every other.
    """
    if form == SCALED:
        unit_m = v_max_mps * control_period_s
        return unit_m, unit_m, v_max_mps
    return rho_cap_m, 0.0, output_scale_mps
