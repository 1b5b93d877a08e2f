"""The floor ratio of two commits, alternating: which change moved an agent's CPU against the floor.

The real / bare ratio of ``bench/bench_runtime.py --floor-only`` holds on a loaded machine better than
absolute figures do, but not across hours: the machine's state moves it too. So this runs both
commits in one invocation, alternating (base, head, base, head, ...), each from its own checkout
(``git worktree add`` of ``--base`` in a temporary directory; head is this working tree) with its
own code on ``PYTHONPATH``, and reports every run's ratio and the machine's load beside it.

Run: ``python bench/investigations/floor_ab.py --base a779117 --counts 6 100 --pairs 2 --update-results``
(writes ``floor_ab.{json,md}`` to the output directory; ``--update-results``: ``bench/results/``).
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from _output import add_output_arguments, output_dir, progress
from _worktree import ROOT, base_worktree, short_commit


def floor_run(tree: Path, count: int, out: Path) -> dict:
    """One ``bench_runtime.py --floor-only`` run of ``count`` robots with ``tree``'s code."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    command = [sys.executable, str(tree / "bench" / "bench_runtime.py"), "--counts", str(count)]
    command += ["--floor-only", "--out", str(out), "--quiet"]
    done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True)
    if done.returncode != 0 or not (out / "runtime.json").exists():
        return {"error": f"exit {done.returncode}: {done.stderr.strip()[-300:]}"}
    row = json.loads((out / "runtime.json").read_text())["floor"][0]
    floor = row.get("floor", {})
    keep = ("real_cpu_ms_per_tick", "bare_cpu_ms_per_tick", "real_over_bare", "window_ticks")
    keep += ("real_main_thread_ms_per_tick", "bare_main_thread_ms_per_tick")
    keep += ("real_zenoh_threads_ms_per_tick", "bare_zenoh_threads_ms_per_tick", "error")
    return {k: floor[k] for k in keep if k in floor} | {
        k: row.get(k)
        for k in ("load_avg_1min_before", "load_avg_1min_after", "other_cores", "error")
        if k in row
    }


def markdown(report: dict) -> str:
    lines = [
        f"`{report['command']}`: `bench/bench_runtime.py --floor-only` (20 s of lockstep sim, bare agents"
        " beside the real ones, both at the runner's agent niceness) of two commits, alternating, in one"
        f" invocation. base = {report['base']}, head = {report['head']}. Main / Zenoh: the same CPU"
        " split into the agent's main thread and Zenoh's threads (ms per tick; '-' where that commit's"
        " benchmark had no split).",
        "",
        "| run | N | commit | real ms/tick | bare ms/tick | real / bare | real main / Zenoh ms"
        " | bare main / Zenoh ms | load before | other cores |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for i, r in enumerate(report["runs"], 1):
        f = lambda key, r=r: "-" if r.get(key) is None else str(r[key])  # noqa: E731
        if "error" in r:
            lines.append(f"| {i} | {r['robots']} | {r['which']} | error: {r['error']} |")
            continue
        lines.append(
            f"| {i} | {r['robots']} | {r['which']} | {f('real_cpu_ms_per_tick')}"
            f" | {f('bare_cpu_ms_per_tick')}"
            f" | **{f('real_over_bare')}** | {f('real_main_thread_ms_per_tick')} /"
            f" {f('real_zenoh_threads_ms_per_tick')} | {f('bare_main_thread_ms_per_tick')} /"
            f" {f('bare_zenoh_threads_ms_per_tick')} | {f('load_avg_1min_before')} | {f('other_cores')} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", required=True, help="the commit to compare this working tree with")
    parser.add_argument("--counts", type=int, nargs="+", default=[6, 100])
    parser.add_argument("--pairs", type=int, default=2, help="base/head pairs per N")
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    out = output_dir(args)
    base, head = short_commit(args.base), short_commit("HEAD")
    if base is None:
        print(f"floor_ab: error: --base {args.base!r}: not a commit of this repository", file=sys.stderr)
        return 2
    runs = []
    plan = [(n, which) for n in args.counts for _ in range(args.pairs) for which in ("base", "head")]
    with base_worktree(args.base, "floor-ab-") as base_tree:
        for i, (count, which) in enumerate(progress(plan, args=args, desc="floor_ab", unit="run")):
            tree = base_tree if which == "base" else ROOT
            runs.append(
                {"robots": count, "which": which} | floor_run(tree, count, base_tree.parent / f"run{i}")
            )
    given = argv if argv is not None else sys.argv[1:]
    command = "python bench/investigations/floor_ab.py " + " ".join(given)
    report = {"command": command, "base": base, "head": f"{head} (working tree)", "runs": runs}
    (out / "floor_ab.json").write_text(json.dumps(report, indent=1) + "\n")
    (out / "floor_ab.md").write_text(markdown(report))
    print(markdown(report))
    return 0 if all("error" not in r for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
