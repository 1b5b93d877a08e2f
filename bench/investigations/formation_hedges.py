"""Can a hand-written rule close ``capt_flood``'s gap on the line of 50 with the same information?

On the line of 50 ``capt_flood``'s median time is 1.14x the lower bound against the expert ``capt``'s
1.03x (``docs/results/tasks/formation-1000-50``): a robot learns of the farthest robot 49 ticks (2.45 s)
after the start and drives meanwhile toward its slot in the CAPT assignment of the robots it knows
(``task_latency.py --task formation`` measures that the gap is that latency). This tries other rules
on the same flood, for the ticks before a robot knows every start (after it, each is ``capt_flood``):

* ``nearest``: head for the nearest slot (whichever robot will take it);
* ``hold``: stand still;
* ``slow``: ``capt_flood``'s partial target at ``v_max`` times the share of starts known (at least 0.3);
* ``phantom``: the CAPT slot of the robots it knows *and* a guess of the others from the prior the
  starts are drawn from (uniform over the sweep's box): the points of a stratified grid over the box
  left after each known start takes its nearest (certainty equivalence);

and one that never stops re-planning:

* ``replan``: every robot floods the freshest position it knows of every robot and re-takes its slot
  every 4 ticks from the CAPT assignment of those positions (D-CAPT's idea of re-assigning from where
  robots are, over a flood instead of meetings).

The formation sweep's starts and graphs of that cell (``swarm.scenarios.task_sweep.cell_starts``) and its
judging (``run_cell``); writes median / p95 of time over the bound and the successes per rule:

    python bench/investigations/formation_hedges.py --graph line --count 50 --starts 100 \
        --rules capt_flood capt nearest hold slow phantom --out bench/results/formation_hedges.md
    python bench/investigations/formation_hedges.py --graph line --count 50 --starts 20 \
        --rules capt_flood replan --out bench/results/formation_hedges_replan.md

(``replan`` computes 50 CAPT assignments per start every 4 ticks, and runs to the time limit when a
start never settles: on two cores 100 starts of it did not finish in 25 minutes, hence 20.)
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from swarm.core.experts import drive_toward_velocity
from swarm.core.initial_poses import box_for
from swarm.core.robot import RobotParams
from swarm.core.tasks import formation
from swarm.scenarios.task_sweep import TaskSweepConfig, cell_starts, run_cell
from swarm.sim.formation_controllers import CaptExpert, CaptFlood
from swarm.sim.links import heard_slots

RULES = ("nearest", "hold", "slow", "phantom")


def stratified_box(count: int) -> np.ndarray:
    """``(count, 2)``: the centres of a near-square grid of ``count`` cells over the sweep's box."""
    low, high = box_for(count)
    columns = math.ceil(math.sqrt(count))
    rows = math.ceil(count / columns)
    xs = low + (np.arange(columns) + 0.5) * (high - low) / columns
    ys = low + (np.arange(rows) + 0.5) * (high - low) / rows
    grid = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    return grid[:count]


def phantom_starts(known: np.ndarray, count: int) -> np.ndarray:
    """The starts of the robots not known yet, guessed from the prior (uniform over the box): the
    stratified grid's points left after each known start takes its nearest free one."""
    free = np.ones(count, dtype=bool)
    grid = stratified_box(count)
    for start in known:
        gaps = np.where(free, np.linalg.norm(grid - start, axis=-1), np.inf)
        free[int(gaps.argmin())] = False
    return grid[free]


class Hedged(CaptFlood):
    """``capt_flood`` with ``rule`` for the ticks before a robot knows every start."""

    def __init__(self, *args, rule: str, **kwargs):
        super().__init__(*args, **kwargs)
        self.rule = rule

    def assign(self, b, members, starts, at_least_m):
        if self.rule != "phantom":
            return super().assign(b, members, starts, at_least_m)
        guessed = np.concatenate([starts, phantom_starts(starts, self.count)])
        return self.slots[formation.capt_assignment(guessed, self.slots)][: len(members)]

    def act(self, poses, points, inbox, heard):
        u_world, memory = super().act(poses, points, inbox, heard)  # fixes self._targets (partial CAPT)
        assert self._targets is not None
        known = memory.reshape(*poses.shape[:2], -1, 3)[..., 0] != 0.0
        everyone = known.all(axis=-1)  # (B, N)
        if everyone.all():
            return u_world, memory
        targets, speed = self._targets, self.robot.v_max_mps
        if self.rule == "phantom":
            return u_world, memory
        if self.rule == "nearest":
            gaps = np.linalg.norm(poses[..., None, :2] - self.slots[None, None], axis=-1)
            targets = np.where(everyone[..., None], targets, self.slots[gaps.argmin(-1)])
        elif self.rule == "hold":
            targets = np.where(everyone[..., None], targets, poses[..., :2])
        else:
            speed = self.robot.v_max_mps * np.maximum(known.sum(-1) / known.shape[-1], 0.3)
        u_world = drive_toward_velocity(poses, targets, speed, self.control_period_s, self.reverse)
        return u_world, memory


class Replan:
    """``replan``: every robot floods the freshest position it knows of every robot, ``(known, x, y,
    tick)``, and every ``every`` ticks takes its slot from the CAPT assignment of those positions (its
    own current one). Views differ while positions travel; once robots stop they agree."""

    centralized = False

    def __init__(self, robot, control_period_s, section, count, every: int = 4, reverse: bool = True):
        self.robot, self.control_period_s, self.count = robot, control_period_s, count
        self.slots = section.slot_positions(count)
        self.message_dim = 4 * count
        self.every, self.reverse = every, reverse
        self.tick = 0
        self._targets: np.ndarray | None = None

    def act(self, poses, points, inbox, heard):
        batch, count = poses.shape[:2]
        memory = inbox[:, :count].reshape(batch, count, count, 4).copy()
        own = np.arange(count)
        memory[:, own, own] = np.concatenate(
            [np.ones((batch, count, 1)), poses[..., :2], np.full((batch, count, 1), self.tick + 1.0)], -1
        )
        for valid, messages in heard_slots(inbox, heard):
            theirs = messages.reshape(batch, count, count, 4)
            newer = valid[..., None] & (theirs[..., 0] != 0.0) & (theirs[..., 3] > memory[..., 3])
            memory[newer] = theirs[newer]
        if self._targets is None or self._targets.shape[:2] != (batch, count):
            self._targets = np.zeros((batch, count, 2))
            self.tick = 0
        if self.tick % self.every == 0:
            for b in range(batch):
                for i in range(count):
                    members = np.flatnonzero(memory[b, i, :, 0] != 0.0)
                    where = memory[b, i, members, 1:3]
                    slot = formation.capt_assignment(where, self.slots)[np.searchsorted(members, i)]
                    self._targets[b, i] = self.slots[slot]
        self.tick += 1
        u_world = drive_toward_velocity(
            poses, self._targets, self.robot.v_max_mps, self.control_period_s, self.reverse
        )
        return u_world, memory.reshape(batch, count, 4 * count)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", default="line", choices=("complete", "cycle", "line", "random"))
    parser.add_argument("--count", type=int, default=50)
    parser.add_argument("--starts", type=int, default=100, help="the sweep's starts of the cell")
    names = ["capt_flood", "capt", *RULES, "replan"]  # capt_flood first: the paired columns need it
    parser.add_argument("--rules", nargs="+", default=names, choices=names, help="which to run")
    parser.add_argument("--out", type=Path, help="markdown file to write (default: print only)")
    args = parser.parse_args(argv)
    config = TaskSweepConfig(
        task="formation",
        topologies=[args.graph],
        sizes=[args.count],
        seeds=args.starts,
        disk_radius_m=3.0,
        chunk_starts=args.starts,  # one chunk: each rule's controller object runs every start at once
    )
    starts = cell_starts(config, args.graph, args.count)
    robot, section = RobotParams(v_max_mps=config.v_max_mps), config.cells.section(args.count)
    period = config.control_period_s
    controllers = {
        "capt": lambda: CaptExpert(robot, period, section),
        "capt_flood": lambda: CaptFlood(robot, period, section, args.count),
        "replan": lambda: Replan(robot, period, section, args.count),
        **{rule: (lambda rule=rule: Hedged(robot, period, section, args.count, rule=rule)) for rule in RULES},
    }
    lines = [
        f"# Formation: rules for the flood's first ticks ({args.graph}, N = {args.count})",
        "",
        f"`python bench/investigations/formation_hedges.py --graph {args.graph} --count {args.count}"
        f" --starts {args.starts} --rules {' '.join(args.rules)} --out {args.out}` (the formation sweep's"
        f" first {args.starts} starts"
        " of the cell; time over the lower bound of the starts that succeeded with 0 conflicts; the"
        " paired columns compare each start's time with capt_flood's on the same start).",
        "",
        "| rule | success (0 conflicts) | median | p95 | per start / capt_flood's, median |"
        " faster / slower than capt_flood |",
        "|---|---|---|---|---|---|",
    ]
    baseline: np.ndarray | None = None  # capt_flood's time / bound per start, for the paired columns
    for name in args.rules:
        began = time.perf_counter()
        cell = run_cell(config, args.graph, args.count, controllers[name](), 0.0, starts=starts)
        values = np.array(
            [
                s["ratio_to_lower_bound"] if s["converged"] and s["conflicts"] == 0 else np.nan
                for s in cell["starts"]
            ]
        )
        if name == "capt_flood":
            baseline = values
        good = values[~np.isnan(values)]
        paired = "- | -"
        if baseline is not None and name != "capt_flood":
            both = ~np.isnan(values) & ~np.isnan(baseline)
            ratio = values[both] / baseline[both]
            paired = f"{np.median(ratio):.3f} | {np.mean(ratio < 1.0):.0%} / {np.mean(ratio > 1.0):.0%}"
        lines.append(
            f"| {name} | {len(good)} of {len(values)} | {np.median(good):.3f} |"
            f" {np.percentile(good, 95):.3f} | {paired} |"
        )
        print(lines[-1], f"({time.perf_counter() - began:.0f} s)", flush=True)
    if args.out is not None:
        args.out.write_text("\n".join(lines) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
