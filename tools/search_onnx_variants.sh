#!/usr/bin/env bash
# Variant search for the learned engine (issue 21), validation part only: every variant is a
# `tools/train_onnx.py --train-only` training (phase 1 only, no export) with the shipped defaults but for the
# flags given below, run side by side, one process each. Written for a lent GPU machine with
# 16 cores (`--device cuda`: the same data, crops and random draws as on the CPU, other
# arithmetic); on the 2-core CPU run one line at a time without `--device cuda`.
#
#   DATA=path/to/defects OUT=dir DEVICE=cuda BUDGET_S=480 tools/search_onnx_variants.sh   (from the repo root)
#
# Each variant's log (OUT/NAME.log) ends with its best mean validation F; `summary.tsv` lists them.
set -u
DATA=${DATA:?DATA: the defects folder (train part is enough)}
OUT=${OUT:?OUT: folder for logs and checkpoints}
DEVICE=${DEVICE:-cpu}
BUDGET_S=${BUDGET_S:-5100}
PY=${PY:-python3}
mkdir -p "$OUT"

variants=(
  "s6k|--max-steps 6000"
  "s6k_seed1|--max-steps 6000 --seed 1"
  "s3k|--max-steps 3000"
  "s10k|--max-steps 10000"
  "s6k_lr2e-3|--max-steps 6000 --lr 2e-3"
  "s6k_enc1|--max-steps 6000 --encoder-lr-mult 1.0"
  "s6k_sev1|--max-steps 6000 --severity-weight 1.0"
  "s3k_b8|--max-steps 3000 --per-class-batch 8"
  "s6k_crop192|--max-steps 6000 --crop-px 192"
  "s6k_wd1e-3|--max-steps 6000 --weight-decay 1e-3"
)

# VARIANTS_FILE: other variants, one "name|flags" a line
if [ -n "${VARIANTS_FILE:-}" ]; then mapfile -t variants <"$VARIANTS_FILE"; fi

pids=()
for v in "${variants[@]}"; do
  name=${v%%|*}; flags=${v#*|}
  # shellcheck disable=SC2086
  OMP_NUM_THREADS=1 $PY tools/train_onnx.py "$DATA" -o "$OUT/$name.onnx" --ckpt "$OUT/$name.pt" --train-only \
    $flags --device "$DEVICE" --time-budget-s "$BUDGET_S" --val-every 500 >"$OUT/$name.log" 2>&1 &
  pids+=($!)
done
wait "${pids[@]}"
for v in "${variants[@]}"; do
  name=${v%%|*}
  printf '%s\t%s\n' "$name" "$(grep -E '^stopped at|^Traceback|Error' "$OUT/$name.log" | tail -1)"
done | tee "$OUT/summary.tsv"
