"""Behavioural cloning: regress the expert's saturated robot-frame velocity on the robot's features.

Reads top to bottom: hyperparameters, data, model, optimiser, loop (checkpoints, CSV log, curve),
export to the torch-free policy file (``swarm.sim.policy``). Loss: MSE in units of ``output_scale_mps``
(the thesis's loss, chapter 3.2), on labels from ``swarm.learn.data`` (saturated, see there).

Presets:

- ``thesis``: the thesis's two-branch model on M and Phi, SGD (lr 0.01, momentum 0.9), Xavier
  uniform init, MSE, 100 epochs (chapter 3.2); batch 64 (the thesis does not say).
- ``default``: the gated graph-filter GNN (``swarm.learn.models.gnn``, K from the data), the loss on the
  saturated output (what the robot applies; the network need not learn the saturation), Adam with a cosine
  schedule and large batches. Why: Adam is insensitive to the very different scales of the hop
  features and of the near-consensus labels, where SGD at 0.01 needs many more epochs; a cosine
  decay to ~0 ends on a low-noise solution without tuning step decays; batches of 4096 make an
  epoch over 10^6 samples take seconds on a laptop CPU, and the model is small enough that
  large batches cost no generalisation.

Run: ``swarm train --algo bc --data data/bc.npz --out runs/bc`` (``--preset thesis`` for the thesis).
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from swarm.core.robot import RobotParams
from swarm.learn.data import load_dataset
from swarm.learn.models import build_model
from swarm.learn.models.base import saturate
from swarm.learn.train import preset_with_overrides
from swarm.sim.features import FeatureSpec


@dataclass(frozen=True)
class BCConfig:
    data: str = "data/bc.npz"
    out: str = "runs/bc"
    seed: int = 0
    # model (swarm.learn.models): kind, hops K (None: all hops in the data), widths
    model: str = "gnn"
    hops: int | None = None
    hidden: int = 64
    layers: int = 2  # gnn: hidden layers of the gate MLP
    # gnn: bounds of the total gain G, 1/s. Fixed at 1/dt by default: a learned G came out timid
    # (MSE shrinks it wherever the expert's direction is uncertain) and 1.3-2.7x slower on sparse
    # graphs; G dt <= 1 keeps the no-overshoot guarantee of swarm.learn.models.gnn.
    gain_min_per_s: float = 20.0
    gain_max_per_s: float = 20.0
    hop1_weight_min: float = 0.1  # gnn
    readout: tuple[int, ...] = (64,)  # gnn_mlp
    odd: bool = True  # gnn_mlp
    symmetrize: bool = True  # gnn_mlp
    branch_width: int = 4  # two_branch
    feature_scale_m: float = 1.0
    output_scale_mps: float | None = None  # None: the robot's v_max (labels then lie in [-1, 1])
    init: str = "default"  # "xavier_uniform" (thesis) or torch's default
    init_from: str | None = None  # start from this policy file's weights (same architecture; DAgger)
    # loss on what the robot applies, sat(model(x)) (the label is saturated too); the thesis
    # regressed the raw output
    saturate_output: bool = True
    # + speed_weight (|u| - |label|)^2: keeps the expert's speed where the direction is uncertain
    # (plain MSE shrinks the output there, towards the mean of the possible labels)
    speed_weight: float = 0.0
    # optimisation
    optimizer: str = "adam"  # or "sgd"
    lr: float = 3e-3
    momentum: float = 0.9  # sgd
    weight_decay: float = 0.0
    schedule: str = "cosine"  # or "constant"
    epochs: int = 20
    batch_size: int = 4096
    val_fraction: float = 0.05
    threads: int = 1  # torch intra-op threads; more only on an idle machine
    progress: bool = True
    extra: dict = field(default_factory=dict)  # free-form notes copied into the policy metadata


PRESETS: dict[str, BCConfig] = {
    "default": BCConfig(),
    "thesis": BCConfig(
        model="two_branch",
        hops=2,
        init="xavier_uniform",
        saturate_output=False,
        optimizer="sgd",
        lr=0.01,
        momentum=0.9,
        schedule="constant",
        epochs=100,
        batch_size=64,
    ),
}


def make_config(preset: str = "default", overrides: dict | None = None) -> BCConfig:
    config = preset_with_overrides("bc", PRESETS, preset, overrides, tuple_fields=("readout",))
    if not Path(config.data).is_file():
        raise ValueError(f"data: no such file {config.data} (make one with 'swarm collect')")
    return config


def model_config(config: BCConfig, spec: FeatureSpec, robot: RobotParams) -> dict:
    architecture: dict = {"kind": config.model}
    if config.model == "gnn":
        architecture.update(
            hidden=config.hidden,
            layers=config.layers,
            gain_min_per_s=config.gain_min_per_s,
            gain_max_per_s=config.gain_max_per_s,
            hop1_weight_min=config.hop1_weight_min,
        )
    elif config.model == "gnn_mlp":
        architecture.update(
            hidden=config.hidden, readout=list(config.readout), odd=config.odd, symmetrize=config.symmetrize
        )
    elif config.model == "two_branch":
        architecture.update(branch_width=config.branch_width)
    return {
        "model": architecture,
        "features": spec.to_dict(),
        "feature_scale_m": config.feature_scale_m,
        "output_scale_mps": config.output_scale_mps or robot.v_max_mps,
    }


def plot_curve(log_rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [row["epoch"] for row in log_rows]
    fig, ax = plt.subplots(figsize=(6, 4), dpi=110)
    ax.plot(epochs, [row["train_loss"] for row in log_rows], label="train")
    ax.plot(epochs, [row["val_loss"] for row in log_rows], label="validation")
    ax.set(yscale="log", xlabel="epoch", ylabel="MSE (units of output scale)", title="behavioural cloning")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def train(config: BCConfig) -> Path:
    """Train, checkpoint every epoch, export the model with the lowest validation loss; returns its path."""
    # -- data: features (S, K, 2) and saturated labels (S, 2), robot frame ------------------------
    dataset = load_dataset(config.data)  # first: a bad file leaves no output folder behind
    out = Path(config.out)
    (out / "checkpoints").mkdir(parents=True, exist_ok=True)
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    rng = np.random.default_rng(config.seed)
    data_spec = dataset.spec
    hops = config.hops or data_spec.hops
    if hops > data_spec.hops:
        raise ValueError(f"model wants {hops} hops, the data has {data_spec.hops}")
    spec = replace(data_spec, hops=hops)
    robot = RobotParams(**dataset.metadata["robot"])
    features = torch.from_numpy(np.ascontiguousarray(dataset.features[:, :hops]))
    labels = torch.from_numpy(dataset.labels)
    order = rng.permutation(len(labels))
    n_val = max(1, int(config.val_fraction * len(labels)))
    val_index, train_index = torch.from_numpy(order[:n_val]), torch.from_numpy(order[n_val:])

    # -- model, optimiser, schedule ----------------------------------------------------------------
    model = build_model(model_config(config, spec, robot))
    if config.init == "xavier_uniform":
        for module in model.modules():
            if isinstance(module, nn.Linear):
                nn.init.xavier_uniform_(module.weight)
                if module.bias is not None:
                    nn.init.zeros_(module.bias)
    if config.init_from is not None:
        with np.load(config.init_from, allow_pickle=False) as file:
            state = {name: torch.from_numpy(file[name]) for name in file.files if name != "__metadata__"}
        model.load_state_dict(state)
    if config.optimizer == "sgd":
        optimizer: torch.optim.Optimizer = torch.optim.SGD(
            model.parameters(), lr=config.lr, momentum=config.momentum, weight_decay=config.weight_decay
        )
    else:
        optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    steps_per_epoch = math.ceil(len(train_index) / config.batch_size)
    total_steps = config.epochs * steps_per_epoch
    scheduler = torch.optim.lr_scheduler.LambdaLR(
        optimizer,
        (lambda step: 0.5 * (1 + math.cos(math.pi * step / total_steps)))
        if config.schedule == "cosine"
        else (lambda step: 1.0),
    )
    scale = model.output_scale_mps

    def loss_of(index: torch.Tensor) -> torch.Tensor:
        u_local = model(features[index])
        if config.saturate_output:
            u_local = saturate(u_local, robot)
        target = labels[index]
        loss = nn.functional.mse_loss(u_local / scale, target / scale)
        if config.speed_weight:
            speed_error = (u_local.norm(dim=-1) - target.norm(dim=-1)) / scale
            loss = loss + config.speed_weight * (speed_error**2).mean()
        return loss

    def validation_loss() -> float:
        with torch.no_grad():
            return float(
                sum(loss_of(chunk) * len(chunk) for chunk in val_index.split(65536)) / len(val_index)
            )

    # -- loop ----------------------------------------------------------------------------------------
    generator = torch.Generator().manual_seed(config.seed)
    log_rows: list[dict] = []
    best = math.inf
    started = time.perf_counter()
    bar = None
    if config.progress:
        from tqdm import tqdm

        bar = tqdm(total=total_steps, unit="step", desc=f"bc {config.model}")
    for epoch in range(1, config.epochs + 1):
        model.train()
        permutation = train_index[torch.randperm(len(train_index), generator=generator)]
        running, seen = 0.0, 0
        for batch in permutation.split(config.batch_size):
            loss = loss_of(batch)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            scheduler.step()
            running += float(loss.detach()) * len(batch)
            seen += len(batch)
            if bar is not None:
                bar.update()
        model.eval()
        row = {
            "epoch": epoch,
            "train_loss": running / seen,
            "val_loss": validation_loss(),
            "lr": optimizer.param_groups[0]["lr"],
            "time_s": round(time.perf_counter() - started, 3),
        }
        log_rows.append(row)
        if bar is not None:
            bar.set_postfix_str(f"epoch {epoch} train {row['train_loss']:.2e} val {row['val_loss']:.2e}")
        checkpoint = {
            "model_config": model.config(),
            "model": model.state_dict(),
            "optimizer": optimizer.state_dict(),
            "epoch": epoch,
            "bc_config": asdict(config),
            "log": log_rows,
        }
        torch.save(checkpoint, out / "checkpoints" / "last.pt")
        if row["val_loss"] < best:
            best = row["val_loss"]
            torch.save(checkpoint, out / "checkpoints" / "best.pt")
        with open(out / "log.csv", "w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(row))
            writer.writeheader()
            writer.writerows(log_rows)
    if bar is not None:
        bar.close()
    plot_curve(log_rows, out / "curve.png")

    # -- export the best model -----------------------------------------------------------------------
    model.load_state_dict(torch.load(out / "checkpoints" / "best.pt", weights_only=False)["model"])
    training = {
        "algo": "bc",
        "config": asdict(config),
        "data": {key: dataset.metadata[key] for key in ("labels", "config") if key in dataset.metadata},
        "samples": len(labels),
        "best_val_loss": best,
        "train_time_s": log_rows[-1]["time_s"],
    }
    (out / "config.json").write_text(json.dumps(asdict(config), indent=2) + "\n")
    return model.export(out / "policy.npz", robot, training)
