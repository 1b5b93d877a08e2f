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
