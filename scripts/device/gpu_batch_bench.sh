#!/usr/bin/env bash
# One call on a lent GPU machine (issue 17): the paper's Table 1 (B clouds × 1 query,
# preprocessing included) on the CPU and on CUDA with the fused Triton UDF and with the torch
# UDF, the stage profile of the predictor on CUDA, and the CUDA-capable tests (the Triton
# kernel, the batched frames and the learned predictor on the GPU).
# Everything lands under $OUT: gpu.md (versions + batch table), profile-cuda.md, tests.txt.
# Sizing (H100/H200 machine): ~1 min of batch tables, ~1 min of profile, ~2 min of tests.
# Usage (repository root; the device's python3 has torch and triton; our other wheels come in
# .whl/, installed into /tmp/site first, see docs/jobs.md "GPU sessions"):
#   OUT=/tmp/out bash scripts/device/gpu_batch_bench.sh
set -u
PY=${PY:-python3}
RUNS=${RUNS:-5}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
mkdir -p "$OUT"
started=$(date +%s)
stamp() { echo "[$(( $(date +%s) - started )) s] $*" >&2; }

{
  echo "# GPU session $(date -u +%F) ($(hostname))"; echo
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1; echo
  "$PY" -c "import torch, numpy, triton; print('torch', torch.__version__, 'cuda', \
torch.cuda.is_available(), 'numpy', numpy.__version__, 'triton', triton.__version__)" 2>&1
  echo
  timeout 240 "$PY" scripts/bench_batch_table.py --runs "$RUNS" --threads 1 \
    --cuda-udf "${CUDA_UDF:-auto,torch}" 2>&1 | grep -v '^USDT'
} > "$OUT/gpu.md" 2>&1
stamp "batch tables done"

timeout 180 "$PY" scripts/profile_predictor.py --device cuda --runs "$RUNS" \
  --config float32/stride2 --config float32/full --workload batch64 --workload pair \
  --workload field > "$OUT/profile-cuda.md" 2> "$OUT/profile-cuda.err"
stamp "profile done"

timeout 200 "$PY" -m pytest -q -p no:cacheprovider -x \
  tests/litege_core/test_device.py tests/litege_core/test_canonical.py \
  tests/litege_core/descriptor/test_descriptor_udf.py \
  tests/litege_core/matching/test_match_search.py tests/litege_core/learned \
  > "$OUT/tests.txt" 2>&1
stamp "tests done (exit $?)"
