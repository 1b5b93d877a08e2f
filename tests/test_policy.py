"""swarm.learn.models and swarm.sim.policy: export, torch-free inference, parity (numpy == torch,
robot == batch)."""

from __future__ import annotations

import copy
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

from swarm.core import graphs, metrics
from swarm.core.initial_poses import random_poses
from swarm.core.robot import RobotParams, rotate
from swarm.learn.models import MODELS, build_model
from swarm.sim.features import FeatureSpec
from swarm.sim.kinematic import KinematicSim
from swarm.sim.policy import Policy, PolicyFormatError, load_policy

ROBOT = RobotParams()
SPECS = {
    "model1": FeatureSpec(1, normaliser="n_minus_1"),
    "model2": FeatureSpec(2),
    "two_branch": FeatureSpec(2, "output", "n_minus_1"),
    "gnn": FeatureSpec(4),
    "gnn_mlp": FeatureSpec(3),
}


def _exported(kind: str, tmp_path, seed: int = 0):
    torch.manual_seed(seed)
    model = MODELS[kind](SPECS[kind])
    path = model.export(tmp_path / f"{kind}.npz", ROBOT, {"note": "test"})
    return model, path


@pytest.mark.parametrize("kind", sorted(MODELS))
def test_numpy_forward_equals_torch(kind, tmp_path):
    model, path = _exported(kind, tmp_path)
    policy = load_policy(path.read_bytes())
    # The oracle is the torch model in float64 with the exported float32 weights, on the same float64
    # features: the numpy policy computes in float64 too, so only the order of the sums differs (worst
    # 1.4e-14 m/s). The float32 oracle this replaces rounded the features to float32 and summed in
    # float32: its error depends on the inputs (up to 5% of its tolerance rtol 1e-4, atol 1e-6 max|u|
    # over 200 seeds) and, reported once in 24 loaded runs, beyond it.
    reference = copy.deepcopy(model).double()
    seed = 0
    rng = np.random.default_rng(seed)
    # the raw outputs, before any speed saturation (which would hide a wrong gain: most outputs at the
    # usual scale saturate), at the usual scale and with small features (2 mm)
    for scale in (0.8, 0.002):
        features = rng.normal(scale=scale, size=(2000, model.spec.hops, 2))
        with torch.no_grad():
            expected = reference(torch.as_tensor(features, dtype=torch.float64)).numpy()
        got = policy.forward(features)
        np.testing.assert_allclose(
            got,
            expected,
            rtol=1e-9,
            atol=1e-12 * max(1.0, np.abs(expected).max()),
            err_msg=f"features: default_rng({seed}).normal(scale={scale}), torch.manual_seed(0) weights",
        )
    rebuilt = build_model(model.config())
    assert type(rebuilt) is type(model)


class _Tap:
    """Runs a controller and keeps what it was given each tick."""

    def __init__(self, controller):
        self.controller, self.message_dim, self.centralized = controller, controller.message_dim, False
        self.ticks = []

    def act(self, poses, points, inbox, heard):
        u_world, outbox = self.controller.act(poses, points, inbox, heard)
        self.ticks.append((poses.copy(), inbox.copy(), heard.dense.copy(), u_world, outbox))
        return u_world, outbox


@pytest.mark.parametrize("kind", sorted(MODELS))
def test_closed_loop_parity(kind, tmp_path):
    """The numpy policy drives the simulator as the torch model does, and one robot's act_one with the
    messages it heard gives exactly its row of the batched act."""
    model, path = _exported(kind, tmp_path, seed=1)
    count = 6
    poses = random_poses(np.random.default_rng(2), 2, count)
    adjacency = graphs.cycle(count)
    policy = Policy.load(path, robot_count=count)
    tap = _Tap(policy)
    numpy_run = KinematicSim(ROBOT, tap, 0.05, poses, adjacency).rollout(40)
    torch_run = KinematicSim(ROBOT, model.controller(ROBOT, count), 0.05, poses, adjacency).rollout(40)
    np.testing.assert_allclose(numpy_run, torch_run, atol=1e-5)
    for tick_poses, inbox, heard, u_world, outbox in tap.ticks[::7]:
        for b in range(2):
            for i in range(count):
                one_u, one_message = policy.act_one(tick_poses[b, i], inbox[b, heard[b, i] > 0])
                np.testing.assert_allclose(one_u, u_world[b, i], atol=1e-10)
                np.testing.assert_allclose(one_message, outbox[b, i], atol=1e-10)


def test_policy_runs_without_torch_in_a_fresh_interpreter(tmp_path):
    _, path = _exported("gnn", tmp_path)
    script = textwrap.dedent(
        f"""
        import sys
        import numpy as np
        import swarm.sim.policy
        policy = swarm.sim.policy.load_policy(open({str(path)!r}, "rb").read())
        u, message = policy.act_one(np.array([0.1, 0.2, 0.3]), np.ones((2, policy.message_dim)))
        assert u.shape == (2,) and message.shape == (policy.message_dim,)
        heavy = [name for name in ("torch", "numba") if name in sys.modules]
        assert not heavy, heavy
        print("ok")
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"


def test_bad_policy_files_are_refused(tmp_path):
    with pytest.raises(PolicyFormatError):
        load_policy(b"not a policy")
    np.savez(tmp_path / "plain.npz", weights=np.zeros(3))
    with pytest.raises(PolicyFormatError, match="metadata"):
        load_policy(tmp_path / "plain.npz")
    _, path = _exported("model1", tmp_path)
    policy = load_policy(path)
    with pytest.raises(PolicyFormatError, match="version"):
        Policy({**policy.metadata, "format_version": 99}, {})


def test_metadata_says_what_was_trained(tmp_path):
    model, path = _exported("gnn", tmp_path)
    meta = load_policy(path).metadata
    assert meta["model"]["kind"] == "gnn" and meta["features"] == model.spec.to_dict()
    assert meta["robot"] == ROBOT.model_dump() and meta["training"] == {"note": "test"}
    assert path.stat().st_size < 100_000


def test_gated_filter_structure():
    """u(0) = 0, rotation-equivariant, and a gain-bounded convex combination of the hop offsets."""
    torch.manual_seed(3)
    model = MODELS["gnn"](FeatureSpec(4), gain_min_per_s=0.5, gain_max_per_s=20.0)
    x = torch.randn(500, 4, 2, dtype=torch.float64)
    model = model.double()
    with torch.no_grad():
        assert torch.all(model(torch.zeros(1, 4, 2, dtype=torch.float64)) == 0)
        angle = 0.7
        rotated = torch.as_tensor(rotate(x.numpy(), np.full((500, 4), angle)))
        np.testing.assert_allclose(
            model(rotated).numpy(), rotate(model(x).numpy(), np.full(500, angle)), atol=1e-9
        )
        offsets = torch.cumsum(x, dim=-2).norm(dim=-1).max(dim=-1).values
        assert torch.all(model(x).norm(dim=-1) <= 20.0 * offsets + 1e-9)


@pytest.mark.parametrize("topology", ["line", "cycle", "star"])
def test_untrained_gated_filter_already_reaches_consensus(topology, tmp_path):
    """The convex-combination structure alone (random weights) brings a connected swarm together."""
    torch.manual_seed(4)
    model = MODELS["gnn"](FeatureSpec(4), gain_min_per_s=0.5, gain_max_per_s=20.0)
    policy = load_policy(model.export(tmp_path / "random.npz", ROBOT))
    poses = random_poses(np.random.default_rng(5), 4, 6)
    adjacency = {"line": graphs.line, "cycle": graphs.cycle, "star": graphs.star}[topology](6)
    trajectory = KinematicSim(ROBOT, policy, 0.05, poses, adjacency).rollout(1200)
    assert np.all(metrics.max_pairwise(trajectory[-1, ..., :2]) < 0.2)
