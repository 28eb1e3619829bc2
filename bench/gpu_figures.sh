#!/bin/bash
# Issue 40's GPU figures in one device lease (~8 minutes on a fresh H100, compiles included):
# the Scorer's clips/s per B with a step profile and kernel traces, then 1,000 standard clips
# from disk through score_batch. Run from the repository root on the device machine; logs and
# traces go to $OUT (or ./gpu-figures). bench/RESULTS.md, 2026-11-27, has the first figures.
set -o pipefail
OUT=${OUT:-gpu-figures}
mkdir -p "$OUT"
export PYTHONPATH=$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import jax, optimistix; print('jax', jax.__version__, jax.devices(), 'optimistix', optimistix.__version__)"
timeout 300 python3 bench/reward.py --batch-sizes 64 1 8 32 --no-baseline --repeats 5 --profile "$OUT/profile" 2>&1 \
    | tee "$OUT/reward.log"
# B=16 compiles score_batch's group program (16 clips per device) before the disk run reuses it
timeout 210 python3 bench/reward.py --batch-sizes 16 --no-baseline --repeats 3 --disk-clips 1000 --dir /tmp/corpus 2>&1 \
    | tee "$OUT/disk.log"
