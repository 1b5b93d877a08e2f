"""Expert data for behavioural cloning, from the batched kinematic simulator (thesis 3.3, fixed).

Every sample is one robot at one tick: its robot-frame features (``swarm.sim.features``, exactly what the
policy will compute there, with the same one-tick message delay, over the scenario's own graph)
and the expert's label. Episodes: every robot random in a box that grows with N, heading uniform,
a minimum separation (``swarm.core.initial_poses``); a mix of graphs (complete, cycle, line, star,
random, disk) and sizes; the states are the ones visited by rolling the expert out in
``KinematicSim`` (or, for DAgger, a ``driver`` controller while the expert labels).

Label (``labels="centralized"``, the default): eq. 3.1 on the complete graph with everyone's
current point (the thesis's expert), ``u = -K sum_j (p_i - p_j)``, in the robot's frame and
*after the robot's own saturation* (``saturate_local_velocity``). Why saturated: the robot applies
that same saturation to whatever the policy outputs, and saturation is idempotent, so a policy
that hits the saturated label moves exactly as the expert moved. The raw label grows like
``N K |p_i - centroid|`` (tens of m/s for a spread swarm, all of it clipped away on the robot),
would dominate the MSE with far-away samples whose magnitude never matters, and would tie the
network's output scale to N, which a robot on a sparse graph cannot know. Saturated, the label lives
in the diamond ``|ux| + (d/l)|uy| <= v_max``: full speed towards the centroid while far, the
expert's proportional law only in the last few centimetres. ``labels="local_consensus"``: eq. 3.1
on the scenario's graph with last tick's neighbour points (``swarm.sim.controllers.LocalConsensus``).

File (one ``.npz``, no pickles): ``features (S, K, 2)`` and ``labels (S, 2)`` float32,
``robot_count``, ``graph`` (index into ``metadata["graphs"]``), ``tick``, and ``__metadata__``
(UTF-8 JSON: format, features, labels, robot, timing, the collect config).
"""

from __future__ import annotations

import json
import math
import zipfile
import zlib
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from swarm.core import metrics, topologies
from swarm.core.experts import complete_consensus_velocity
from swarm.core.initial_poses import box_for, random_poses
from swarm.core.robot import RobotParams, rotate, world_to_local
from swarm.scenarios.sweep import connecting_radius
from swarm.sim import kernels
from swarm.sim.controllers import BatchedController
from swarm.sim.features import FeatureSpec, batched_features, messages, saturate_local_velocity
from swarm.sim.kinematic import KinematicSim
from swarm.sim.links import Links

FORMAT = "gnn-swarm-dataset"
FORMAT_VERSION = 1
METADATA_KEY = "__metadata__"
GRAPH_KINDS = topologies.kinds(grid=True)  # a sample's ``graph`` is its kind's index here


@dataclass(frozen=True)
class CollectConfig:
    samples: int = 1_000_000
    graphs: tuple[str, ...] = GRAPH_KINDS
    sizes: tuple[int, ...] = (4, 5, 6, 8, 10, 12)
    hops: int = 8  # K: features Phi1..PhiK (a superset for every model with K' <= K, same options)
    phi_source: Literal["m", "output"] = "m"
    normaliser: Literal["degree", "n_minus_1"] = "degree"
    labels: str = "centralized"  # or "local_consensus"
    gain: float = 1.0  # K of eq. 3.1, 1/s
    v_max_mps: float = 0.5
    # the rest of the robot (swarm.core.robot.RobotParams; swarm collect --robot-from SCENARIO)
    half_axle_m: float = 0.1
    offset_m: float = 0.05
    wheel_radius_m: float = 0.04
    body_radius_m: float = 0.12
    control_period_s: float = 0.05
    episode_factor: float = 1.25  # longest episode = factor x (box half-diagonal / v_max)
    settled_m: float = 0.2  # an episode ends once max_pairwise has stayed <= settled_m for tail_s
    tail_s: float = 2.0
    episodes_min: int = 8  # per (graph, size) cell; more when the cell's share of samples needs them
    min_separation_m: float = 0.4
    random_p: tuple[float, float] = (0.2, 0.7)  # Erdos-Renyi link probability, uniform, connected
    disk_radius_factor: tuple[float, float] = (1.0, 1.5)  # x the median connecting radius of the starts
    seed: int = 0

    @property
    def spec(self) -> FeatureSpec:
        return FeatureSpec(self.hops, self.phi_source, self.normaliser)

    @property
    def robot(self) -> RobotParams:
        return RobotParams(
            v_max_mps=self.v_max_mps,
            half_axle_m=self.half_axle_m,
            offset_m=self.offset_m,
            wheel_radius_m=self.wheel_radius_m,
            body_radius_m=self.body_radius_m,
        )

    def check(self) -> None:
        self.spec  # noqa: B018 (validates the feature options)
        known = topologies.kinds(grid=True)
        unknown = sorted(set(self.graphs) - set(known))
        if unknown:
            raise ValueError(f"graphs: unknown graph kind {unknown[0]!r}; choose from {list(known)}")
        if self.labels not in ("centralized", "local_consensus"):
            raise ValueError(f"labels must be 'centralized' or 'local_consensus', got {self.labels!r}")
        if self.samples < 1 or min(self.sizes) < 2:
            raise ValueError("need samples >= 1 and every size >= 2")


PRESETS: dict[str, CollectConfig] = {
    "default": CollectConfig(),
    # The thesis's recipe: complete graph, 6 robots, M and Phi normalised by N - 1 (but every robot
    # randomized, not only two); 10^5 samples so that its 100 SGD epochs at batch 64 take minutes.
    "thesis": CollectConfig(
        samples=100_000, graphs=("complete",), sizes=(6,), hops=2, normaliser="n_minus_1"
    ),
}


def collect_config(preset: str = "default", **overrides: Any) -> CollectConfig:
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(PRESETS)}")
    known = {item.name for item in fields(CollectConfig)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ValueError(f"unknown collect option {unknown[0]!r}")
    config = replace(PRESETS[preset], **{key: value for key, value in overrides.items() if value is not None})
    config.check()
    return config


@dataclass
class Dataset:
    features: np.ndarray  # (S, K, 2) float32, robot frame, metres
    labels: np.ndarray  # (S, 2) float32, robot frame, m/s, saturated
    robot_count: np.ndarray  # (S,)
    graph: np.ndarray  # (S,) index into metadata["graphs"]
    tick: np.ndarray  # (S,)
    metadata: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def spec(self) -> FeatureSpec:
        return FeatureSpec.from_dict(self.metadata["features"])

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = {"format": FORMAT, "format_version": FORMAT_VERSION, **self.metadata}
        encoded = np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)
        with open(path, "wb") as file:
            arrays: dict[str, Any] = {
                "features": self.features,
                "labels": self.labels,
                "robot_count": self.robot_count,
                "graph": self.graph,
                "tick": self.tick,
                METADATA_KEY: encoded,
            }
            np.savez(file, **arrays)
        return path


def load_dataset(path: str | Path) -> Dataset:
    """Read a dataset written by :meth:`Dataset.save`. A file that cannot be read as one (truncated,
    damaged, another format) raises ``ValueError`` naming the file and why, in one line."""
    try:
        with np.load(path, allow_pickle=False) as file:
            metadata = json.loads(file[METADATA_KEY].tobytes().decode("utf-8"))
            if metadata.get("format") != FORMAT or metadata.get("format_version") != FORMAT_VERSION:
                raise ValueError(f"{path}: not a {FORMAT} v{FORMAT_VERSION} file")
            return Dataset(
                file["features"], file["labels"], file["robot_count"], file["graph"], file["tick"], metadata
            )
    except FileNotFoundError:
        raise
    except ValueError as error:
        if str(error).startswith(f"{path}: "):
            raise
        raise ValueError(f"{path}: not a readable dataset (truncated or damaged?): {error}") from None
    except (OSError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as error:
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise ValueError(f"{path}: not a readable dataset (truncated or damaged?): {reason}") from None


class ExpertRecorder:
    """A batched controller that records (features, expert label) for every robot that heard someone.

    It moves the robots with the expert's saturated velocity, or with ``driver`` when given
    (DAgger: the learner's states, the expert's labels), and broadcasts the messages the policy
    would broadcast, so every simulator tick has the policy's information timing.
    """

    centralized = False

    def __init__(
        self,
        spec: FeatureSpec,
        robot: RobotParams,
        labels: str = "centralized",
        gain: float = 1.0,
        driver: BatchedController | None = None,
    ):
        self.spec, self.robot, self.labels, self.gain, self.driver = spec, robot, labels, gain, driver
        self.message_dim = spec.message_dim
        self.recorded: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.tick = 0

    def expert_velocity(self, points: np.ndarray, inbox: np.ndarray, heard: Links) -> np.ndarray:
        if self.labels == "centralized":
            return complete_consensus_velocity(points, self.gain)
        u_world = np.empty_like(points)
        neighbour_points = np.ascontiguousarray(inbox[..., :2])
        kernels.delayed_consensus(points, neighbour_points, heard.index, heard.weight, self.gain, u_world)
        return u_world

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        theta = poses[..., 2]
        features_local, phi_world = batched_features(poses, points, inbox, heard, self.spec)
        label_local = saturate_local_velocity(
            world_to_local(self.expert_velocity(points, inbox, heard), theta), self.robot
        )
        informed = heard.heard_count() > 0  # a robot that heard nobody has no features to learn from
        if informed.any():
            self.recorded.append(
                (features_local[informed], label_local[informed], np.full(informed.sum(), self.tick))
            )
        self.tick += 1
        if self.driver is not None:
            u_world, _ = self.driver.act(poses, points, inbox, heard)
        else:
            u_world = rotate(label_local, theta)
        return u_world, messages(points, phi_world, u_world, self.spec)

    def take(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        features, labels, ticks = (np.concatenate(column) for column in zip(*self.recorded, strict=True))
        self.recorded = []
        return features.astype(np.float32), labels.astype(np.float32), ticks.astype(np.uint16)


def episode_graphs(
    kind: str, count: int, batch: int, positions: np.ndarray, config: CollectConfig, rng: np.random.Generator
) -> tuple[np.ndarray | None, float | None]:
    """``(B, N, N)`` adjacency, or a disk radius for proximity graphs (connecting most starts)."""
    topology = topologies.get(kind)
    if topology.proximity:
        factor = rng.uniform(*config.disk_radius_factor)
        return None, float(np.median([connecting_radius(start[None]) for start in positions]) * factor)
    if topology.random:
        p = rng.uniform(*config.random_p, size=batch)
        seeds = rng.integers(0, 2**31, size=batch)
        pairs = zip(p, seeds, strict=True)
        params = [topologies.Params(float(pi), int(s), connected=True) for pi, s in pairs]
        return np.stack([topology.fixed(count, one) for one in params]), None
    return np.broadcast_to(topology.fixed(count), (batch, count, count)), None


def rollout_batch(
    config: CollectConfig,
    kind: str,
    count: int,
    batch: int,
    rng: np.random.Generator,
    driver: BatchedController | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``batch`` episodes of one (graph, size) cell; each ends once settled for ``tail_s``.

    Returns features ``(S, K, 2)``, labels ``(S, 2)`` and ticks ``(S,)`` of every informed robot-tick.
    """
    robot = config.robot
    box = box_for(count)
    steps = math.ceil(
        config.episode_factor * math.sqrt(2) * box[1] / robot.v_max_mps / config.control_period_s
    )
    poses = random_poses(rng, batch, count, box, box, config.min_separation_m)
    adjacency, radius = episode_graphs(kind, count, batch, poses[..., :2], config, rng)
    recorder = ExpertRecorder(config.spec, robot, config.labels, config.gain, driver)
    sim = KinematicSim(robot, recorder, config.control_period_s, poses, adjacency, radius)
    tail_ticks = round(config.tail_s / config.control_period_s)
    settled_for = np.zeros(batch, dtype=np.int64)
    for _ in range(steps):
        sim.step()
        settled = metrics.max_pairwise(sim.poses[..., :2]) <= config.settled_m
        settled_for = np.where(settled, settled_for + 1, 0)
        running = settled_for < tail_ticks
        if not running.all():
            if not running.any():
                break
            sim.keep(running)
            settled_for = settled_for[running]
    return recorder.take()


def collect(config: CollectConfig, driver_for=None, progress: bool = True) -> Dataset:
    """Roll out the expert (or ``driver_for(robot_count)``'s controller) in every (graph, size) cell.

    Each cell gets an equal share of ``config.samples``: batches of episodes until the share is
    filled, then a random subset of exactly that share, so that no tick range is favoured.
    """
    config.check()
    rng = np.random.default_rng(config.seed)
    cells = [(kind, count) for kind in config.graphs for count in config.sizes]
    shares = np.diff(np.linspace(0, config.samples, len(cells) + 1).round().astype(int))
    columns: list[tuple[np.ndarray, ...]] = []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=config.samples, unit="sample", unit_scale=True, desc="collect")
    for (kind, count), share in zip(cells, shares, strict=True):
        if bar is not None:
            bar.set_postfix_str(f"{kind} N={count}")
        driver = driver_for(count) if driver_for is not None else None
        parts, have, per_episode = [], 0, None
        while have < share:
            guess = per_episode or count * config.episode_factor * 50  # samples per episode, first guess
            batch = max(config.episodes_min, math.ceil(1.1 * (share - have) / guess))
            part = rollout_batch(config, kind, count, batch, rng, driver)
            parts.append(part)
            have += len(part[1])
            per_episode = max(1.0, len(part[1]) / batch)
        features, labels, ticks = (np.concatenate(column) for column in zip(*parts, strict=True))
        chosen = np.sort(rng.choice(len(labels), size=share, replace=False))
        columns.append(
            (
                features[chosen],
                labels[chosen],
                np.full(share, count, dtype=np.uint16),
                np.full(share, topologies.grid_index(kind), dtype=np.uint8),
                ticks[chosen],
            )
        )
        if bar is not None:
            bar.update(share)
    if bar is not None:
        bar.close()
    features, labels, robot_count, graph, tick = (
        np.concatenate(column) for column in zip(*columns, strict=True)
    )
    metadata = {
        "features": config.spec.to_dict(),
        "labels": config.labels,
        "label_frame": "robot",
        "label_saturated": True,
        "robot": config.robot.model_dump(),
        "control_period_s": config.control_period_s,
        "graphs": list(topologies.kinds(grid=True)),
        "config": asdict(config),
    }
    return Dataset(features, labels, robot_count, graph, tick, metadata)
