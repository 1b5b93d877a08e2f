"""A committed ``swarm evaluate`` cell of the rendezvous GNN rerun on each of several OpenBLAS kernels.

The companion of ``blas_kernels.py`` (task sweeps) for the learned rendezvous model's evaluation cells
(``docs/results/gnn_eval/*/cells/<topology>_<N>_gnn-<hash>.npz``: per start, the time to converge and
the graph's algebraic connectivity ``lambda2``, an eigenvalue that LAPACK computes on OpenBLAS). Each
``--cells`` entry ``topology:N`` is rerun by ``swarm evaluate MODEL --topologies T --sizes N`` in a
child process started with ``OPENBLAS_CORETYPE`` set, once per ``--kernels`` entry (the baselines'
cells taken from ``--reuse``, so only the model runs), and its cell compared with the committed one:
starts with the same time, how many moved and by how much, the medians, and whether ``lambda2`` is
the same bits.

    python bench/investigations/blas_kernels_rendezvous.py --evaluation docs/results/gnn_eval/default \\
        --cells cycle:12 line:12 --kernels Haswell SkylakeX --out bench/results/blas_kernels_rendezvous.md

Exit 0 when every rerun is done (whatever it found), 1 when one failed, 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--evaluation", type=Path, required=True, help="a swarm evaluate --out (its cells/)")
    parser.add_argument("--cells", nargs="+", required=True, help="topology:N")
    parser.add_argument(
        "--kernels", nargs="+", default=["Haswell", "SkylakeX"], help="OPENBLAS_CORETYPE values"
    )
    parser.add_argument("--out", type=Path, required=True, help="markdown file written")
    args = parser.parse_args(argv)
    config_path = args.evaluation / "evaluation_config.json"
    if not config_path.is_file():
        parser.error(f"--evaluation {args.evaluation}: no evaluation_config.json there")
    config = json.loads(config_path.read_text())
    model = Path(config["model"])
    if not model.is_file():
        parser.error(f"{config_path}: model {model} does not exist")
    lines = [
        f"Committed `swarm evaluate` cells of `{args.evaluation}` (model `{model}`) rerun on OpenBLAS"
        " kernels (`OPENBLAS_CORETYPE`). Written by `python bench/investigations/blas_kernels_rendezvous.py"
        f" {' '.join(argv if argv is not None else sys.argv[1:])}`.",
        "",
        "| cell | kernel | starts with the same time | moved: at most (s) | median time committed / rerun (s)"
        " | `lambda2` the same bits |",
        "|---|---|---|---|---|---|",
    ]
    failed = False
    for cell in args.cells:
        parts = cell.split(":")
        if len(parts) != 2 or not parts[1].isdigit():
            parser.error(f"--cells {cell!r}: want topology:N")
        topology, count = parts
        committed_paths = sorted((args.evaluation / "cells").glob(f"{topology}_{count}_gnn-*.npz"))
        if len(committed_paths) != 1:
            parser.error(
                f"--cells {cell!r}: want one {topology}_{count}_gnn-*.npz in {args.evaluation}/cells"
            )
        committed = np.load(committed_paths[0])
        for kernel in args.kernels:
            with tempfile.TemporaryDirectory() as scratch:
                command = [
                    sys.executable,
                    "-m",
                    "swarm.cli",
                    "evaluate",
                    str(model),
                    "--topologies",
                    topology,
                ]
                command += ["--sizes", count, "--reuse", *config["reuse"], "--curve-sizes", count]
                command += ["--curve-starts", "1", "--max-duration", str(config["max_duration_s"])]
                command += ["--out", scratch, "--quiet"]
                done = subprocess.run(command, env=os.environ | {"OPENBLAS_CORETYPE": kernel}, check=False)
                rerun_path = Path(scratch) / "cells" / committed_paths[0].name
                if done.returncode != 0 or not rerun_path.is_file():
                    lines.append(f"| {cell} | {kernel} | failed (exit {done.returncode}) | | | |")
                    failed = True
                    continue
                rerun = np.load(rerun_path)
                times, before = rerun["times_s"], committed["times_s"]
                differ = ~((times == before) | (np.isnan(times) & np.isnan(before)))
                largest = float(np.nanmax(np.abs(times - before)[differ])) if differ.any() else 0.0
                same_lambda2 = bool(np.array_equal(rerun["lambda2"], committed["lambda2"]))
            lines.append(
                f"| {cell} | {kernel} | {int((~differ).sum())} of {len(times)} | {int(differ.sum())}:"
                f" {largest:.3g} | {np.nanmedian(before):.4g} / {np.nanmedian(times):.4g} | {same_lambda2} |"
            )
            print(lines[-1], flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
