#!/usr/bin/env bash
# One call on a lent GPU machine (16 cores, one GPU; see docs/jobs.md, "GPU sessions"):
#   1. issue 17: the paper's Table 1 (B clouds × 1 query) on CPU and CUDA, and the CUDA tests;
#   2. issue 15: procedural T-Net shapes generated on the CPU cores, then two T-Nets trained on
#      the GPU side by side (batches sampled by loader processes), each fit to a time budget.
# Everything comes back under $OUT (8 files, the limit): gpu.md, shapes.log, tnet-a/*, tnet-b/*.
# Sizing (H100 machine, 2026-11-26): ~1 s per shape per generating process (2,000 shapes on 14:
# ~150 s), benchmarks + CUDA tests ~140 s meanwhile, ~23 steps/s per training with 7 loader
# processes; a 9.5-minute call fits BUDGET=5 with the reports.
# Usage (repository root; the device's python3 has torch; our wheels come in .whl/):
#   OUT=/tmp/out N_TRAIN=2000 BUDGET=5 bash scripts/device/tnet_and_bench.sh
# Scaled down for a rehearsal on a laptop: N_TRAIN=24 N_VAL=4 BUDGET=0.2 WORKERS=2 BENCH_RUNS=1.
set -u
PY=${PY:-python3}
N_TRAIN=${N_TRAIN:-2000}
N_VAL=${N_VAL:-40}
BUDGET=${BUDGET:-5}
WORKERS=${WORKERS:-14}          # shape generation; each training gets half as loader processes
BENCH_RUNS=${BENCH_RUNS:-5}
BENCH_CPUS=${BENCH_CPUS:-14,15}
WORK_CPUS=${WORK_CPUS:-0-13}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
SHAPES=out/tnet-shapes-gpu
mkdir -p "$OUT" "$SHAPES"
started=$(date +%s)
stamp() { echo "[$(( $(date +%s) - started )) s] $*"; }
command -v taskset > /dev/null || taskset() { shift 2; "$@"; }

stamp "generating $N_TRAIN + $N_VAL shapes on $WORKERS processes"
taskset -c "$WORK_CPUS" "$PY" -c "
from litege_core.train.tnet import generate_shape_set
import time
for split, n in (('train', $N_TRAIN), ('val', $N_VAL)):
    tick = time.time()
    generate_shape_set('quadruped', split, n, '$SHAPES', workers=$WORKERS)
    print(split, n, 'shapes in', round(time.time() - tick, 1), 's')
" > "$OUT/shapes.log" 2>&1 &
shapes_pid=$!

{
  echo "# GPU session $(date -u +%F) ($(hostname))"; echo
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1; echo
  "$PY" -c "import torch, numpy; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'numpy', numpy.__version__)"
  echo; stamp "batch table"
  timeout 150 taskset -c "$BENCH_CPUS" "$PY" scripts/bench_batch_table.py --runs "$BENCH_RUNS" --threads 1 2>&1
  echo; stamp "CUDA tests"; echo '```'
  timeout 90 taskset -c "$BENCH_CPUS" "$PY" -m pytest -q -p no:cacheprovider \
    tests/litege_core/test_device.py tests/litege_core/descriptor/test_descriptor_udf.py \
    tests/litege_core/matching/test_match_search.py tests/litege_core/learned 2>&1 | tail -25
  echo '```'
} > "$OUT/gpu.md" 2>&1
stamp "benchmarks done"
wait "$shapes_pid"
stamp "shapes done: $(tail -1 "$OUT/shapes.log")"

half=$(( WORKERS / 2 > 0 ? WORKERS / 2 : 1 ))
train_tnet() {  # NAME CONV_WIDTHS; only tnet.safetensors, report.json, train.log land in $OUT
  local dir="$OUT/tnet-$1" scratch="/tmp/tnet-$1"
  mkdir -p "$dir" "$scratch"
  sed -e "s|^n_train = .*|n_train = $N_TRAIN|" -e "s|^n_val = .*|n_val = $N_VAL|" \
      -e "s|^cache_dir = .*|cache_dir = \"$SHAPES\"|" -e "s|^conv_widths = .*|conv_widths = $2|" \
      configs/tnet-quadrupeds-gpu.toml > "$scratch/config.toml"
  taskset -c "$WORK_CPUS" "$PY" -m litege_core.cli train tnet --config "$scratch/config.toml" \
    --out "$dir" --workers "$half" --time-budget "$BUDGET" > "$scratch/result.json" \
    2> "$scratch/stderr.log" || tail -40 "$scratch/stderr.log" > "$scratch/result.json"
  cat "$scratch/result.json" >> "$dir/train.log"
}
stamp "training two T-Nets, $BUDGET min each"
train_tnet a "[64, 128, 256]" &
train_tnet b "[64, 128, 512]" &
wait
stamp "done"
