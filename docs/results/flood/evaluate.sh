#!/bin/sh
# The evaluation of the learned max-flooding GNN (1000 starts per cell, kinematic engine, the
# compiled batched forward), run from the project root under `nice -n 10`; the sweeps are
# independent (one at a time on a shared 2-core machine). MODEL: the policy file evaluated;
# PREVIOUS: the earlier flooding model shown beside it. Cells are cached under the file's hash
# (`cells/`), so a sweep that is re-run reuses every cell it already has, and one directory holds
# the cells of several models.
set -e
MODEL=${MODEL:-models/gnn_flood.npz}
PREVIOUS=${PREVIOUS:-models/gnn_flood_imitation.npz}
OUT=${OUT:-docs/results/flood}
for M in $PREVIOUS $MODEL; do
    S="swarm sweep --controllers gnn --model $M --seeds 1000 --max-duration 300 --quiet"
    $S --topologies cycle line --sizes 24 100 --packet-loss 0.5 --out $OUT/eval_loss50
    $S --topologies cycle line --sizes 24 100 --packet-loss 0.2 --out $OUT/eval_loss20
    $S --topologies complete cycle line --sizes 6 12 24 50 100 --out $OUT/eval_a
    $S --topologies star random disk --sizes 6 12 24 50 100 --out $OUT/eval_b
    $S --topologies line_sorted --sizes 6 12 24 50 100 --out $OUT/eval_sorted
done
# The lossless cells of PREVIOUS in eval_a and eval_b were run before the rule "holds still until
# it has heard a neighbour once" replaced "holds still in a tick it hears nobody": a sample of them
# re-run with the new rule, per start (recheck.md: identical)
swarm sweep --controllers gnn --model $PREVIOUS --seeds 1000 --max-duration 300 --quiet \
    --topologies complete cycle line star random disk --sizes 6 24 --out $OUT/eval_recheck
python bench/investigations/compare_cells.py --before $OUT/eval_a $OUT/eval_b --after $OUT/eval_recheck \
    --out $OUT/recheck.md
# where the previous model lost time at N = 6: its target or its learned steering
python bench/investigations/flood_n6_limit.py --model $PREVIOUS --sizes 6 --starts 200 --out $OUT/n6_limit.md
python bench/investigations/flood_n6_limit.py --model $MODEL --sizes 6 --starts 200 --out $OUT/n6_limit_steering.md
# mec_flood's cells beside it: bench/baselines.py (its docstring); here the ones the GNN's table
# needed (disk and line_sorted); the tables read every cache, the model's cells included
python bench/baselines.py --out docs/results/baselines --only mec_flood --graphs disk line_sorted \
    --reuse docs/results/consensus_sweep docs/results/gnn_eval/default docs/results/gnn_eval/disk \
    $OUT/eval_a $OUT/eval_b $OUT/eval_sorted $OUT/eval_loss50 $OUT/eval_loss20 --model $MODEL
# the table reads the per-cell results (cells/), so it can also be made while sweeps still run
python bench/flood_table.py --model $MODEL --previous-model $PREVIOUS \
    --new-cells $OUT/eval_a $OUT/eval_b $OUT/eval_sorted $OUT/eval_loss50 $OUT/eval_loss20 \
    --old docs/results/gnn_eval/default/evaluation.csv docs/results/gnn_eval/disk/evaluation.csv \
    --baselines docs/results/baselines/baselines.csv --out $OUT/comparison.md
