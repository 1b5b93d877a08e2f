"""Can a hand-written rule close ``capt_flood``'s gap on the line of 50 while the flood is incomplete?

``bench/formation.py`` measured ``capt_flood`` on the line of 50 at a median of 1.161x the lower bound
(p95 1.374) against the expert ``capt``'s 1.029x: on a line a robot learns of the farthest robot 49
ticks (2.45 s) after the start and drives meanwhile toward the slot of a partial CAPT assignment. This
tries three rules for the time before a robot knows every start (after it, each is ``capt_flood``):

* ``nearest``: head for the nearest slot (whichever robot will take it);
* ``hold``: stand still;
* ``slow``: ``capt_flood``'s partial target at ``v_max`` times the share of starts known (at least 0.3).

Same starts, graphs and rule as the bench (``bench/formation.py``'s ``starts`` and cell); prints
median / p95 of time over the bound and the success rate per rule:

    python bench/investigations/formation_hedges.py --graph line --count 50 --starts 20 \
        > bench/results/formation_hedges.txt
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import formation as bench

from swarm.core import topologies
from swarm.core.experts import drive_toward_velocity
from swarm.core.robot import RobotParams
from swarm.core.tasks import formation
from swarm.sim.formation_controllers import CaptExpert, CaptFlood
from swarm.sim.kinematic import KinematicSim

RULES = ("nearest", "hold", "slow")


class Hedged(CaptFlood):
    """``capt_flood`` with ``rule`` for the ticks before a robot knows every start."""

    def __init__(self, *args, rule: str, **kwargs):
        super().__init__(*args, **kwargs)
        self.rule = rule

    def act(self, poses, points, inbox, heard):
        u_world, memory = super().act(poses, points, inbox, heard)  # fixes self._targets (partial CAPT)
        assert self._targets is not None
        known = memory.reshape(*poses.shape[:2], -1, 3)[..., 0] != 0.0
        everyone = known.all(axis=-1)  # (B, N)
        if everyone.all():
            return u_world, memory
        targets, speed = self._targets, self.robot.v_max_mps
        if self.rule == "nearest":
            gaps = np.linalg.norm(poses[..., None, :2] - self.slots[None, None], axis=-1)
            targets = np.where(everyone[..., None], targets, self.slots[gaps.argmin(-1)])
        elif self.rule == "hold":
            targets = np.where(everyone[..., None], targets, poses[..., :2])
        else:
            speed = self.robot.v_max_mps * np.maximum(known.sum(-1) / known.shape[-1], 0.3)
        u_world = drive_toward_velocity(poses, targets, speed, self.control_period_s, self.reverse)
        return u_world, memory


def run(graph: str, count: int, poses: np.ndarray, controller) -> tuple[float, float, float]:
    robot, section = RobotParams(), bench.section_for(count)
    slots = section.slot_positions(count)
    rng = np.random.default_rng(count)  # the bench's graphs: one per start for a random kind
    adjacency = np.stack([topologies.draw(graph, count, rng) for _ in range(len(poses))])
    sim = KinematicSim(robot, controller, bench.CONTROL_PERIOD_S, poses, adjacency=adjacency)
    hold_ticks = round(section.hold_s / bench.CONTROL_PERIOD_S)
    ok = [formation.occupied(sim.poses[..., :2], slots, section.tolerance_m)]
    while sim.time_s < bench.MAX_DURATION_S:
        sim.step()
        ok.append(formation.occupied(sim.poses[..., :2], slots, section.tolerance_m))
        if len(ok) > hold_ticks and np.all(np.stack(ok[-hold_ticks - 1 :]), axis=0).all():
            break
    held = np.stack(ok)
    times = np.arange(len(held)) * bench.CONTROL_PERIOD_S
    ratios = []
    for b in range(len(poses)):
        settled = formation.settle_time(times, held[:, b], section.hold_s)
        bound = formation.lower_bound_s(poses[b, :, :2], section, robot.v_max_mps)
        ratios.append(np.nan if settled is None else settled / bound)
    values = np.array(ratios)
    done = values[~np.isnan(values)]
    return float(np.median(done)), float(np.percentile(done, 95)), float(np.mean(~np.isnan(values)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", default="line", choices=("complete", "cycle", "line", "random"))
    parser.add_argument("--count", type=int, default=50)
    parser.add_argument("--starts", type=int, default=20)
    args = parser.parse_args(argv)
    poses = bench.starts(
        args.graph, args.count, args.starts, seed=1000 * args.count + bench.GRAPHS.index(args.graph)
    )
    robot, section = RobotParams(), bench.section_for(args.count)
    print(f"{args.graph}, N = {args.count}, {args.starts} starts (bench/formation.py's): time / bound")
    controllers = {
        "capt": lambda: CaptExpert(robot, bench.CONTROL_PERIOD_S, section),
        "capt_flood": lambda: CaptFlood(robot, bench.CONTROL_PERIOD_S, section, args.count),
        **{
            rule: (lambda rule=rule: Hedged(robot, bench.CONTROL_PERIOD_S, section, args.count, rule=rule))
            for rule in RULES
        },
    }
    for name, build in controllers.items():
        began = time.perf_counter()
        median, p95, success = run(args.graph, args.count, poses, build())
        print(
            f"{name:>10}: median {median:.3f}, p95 {p95:.3f}, success {success:.0%}"
            f" ({time.perf_counter() - began:.0f} s)",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
