#!/bin/sh
# The evaluation of the learned max-flooding GNN (1000 starts per cell, kinematic engine, the
# compiled batched forward), run from the project root; the four sweeps are independent (they ran
# two at a time). MODEL: the policy file evaluated (the cells are cached under its hash).
set -e
MODEL=${MODEL:-models/gnn_flood.npz}
OUT=${OUT:-docs/results/flood}
S="swarm sweep --controllers gnn --model $MODEL --seeds 1000 --max-duration 300 --quiet"
$S --topologies complete cycle line --sizes 6 12 24 50 100 --out $OUT/eval_a
$S --topologies star random disk --sizes 6 12 24 50 100 --out $OUT/eval_b
$S --topologies line_sorted --sizes 100 --out $OUT/eval_sorted
$S --topologies cycle line --sizes 24 100 --packet-loss 0.5 --out $OUT/eval_loss50
# the table reads the per-cell results (cells/), so it can also be made while sweeps still run
python bench/flood_table.py --model $MODEL \
    --new-cells $OUT/eval_a $OUT/eval_b $OUT/eval_sorted $OUT/eval_loss50 \
    --old docs/results/gnn_eval/default/evaluation.csv docs/results/gnn_eval/disk/evaluation.csv \
    --out $OUT/comparison.md
