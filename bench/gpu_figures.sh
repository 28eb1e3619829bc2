#!/bin/bash
# GPU figures in one device lease, logs and traces into $OUT (or ./gpu-figures). Run from the
# repository root on the device machine:
#   bench/gpu_figures.sh reward      issues 40, 61: the Scorer's clips/s per B with a step profile and
#                                    kernel traces, then 1,000 standard clips from disk (~8 min)
#   bench/gpu_figures.sh pose        issue 61: the Scorer at B = 64 with each stage timed and a kernel
#                                    trace, 1,000 standard clips from disk, the least-squares step's forms
#                                    and the histograms' copies timed alone (~9 min); a form that wins
#                                    alone: bench/reward.py --linearise FORM
#   bench/gpu_figures.sh histograms  issue 61: the histograms' copies timed alone, then the Scorer at
#                                    B = 64 with one copy and with $HISTOGRAM_COPIES (default 32), each
#                                    stage timed (~8 min)
#   bench/gpu_figures.sh forms       issue 61: the least-squares step's forms alone, then the Scorer at
#                                    B = 64 with the accelerator's stacked form of before 2026-12-04
#                                    and with 28 reductions side by side, each stage timed (~8 min)
#   bench/gpu_figures.sh widths      issue 61, item 2: the least-squares step and an LM solve alone at
#                                    960 down to 60 pairs: whether a step's time follows the lanes it
#                                    holds (what leaving finished pairs out could save) (~3 min)
#   bench/gpu_figures.sh lanes       issue 61, item 2: the Scorer at B = 64, each stage timed, with the
#                                    draws' and least-squares solves' finished lanes left behind (the
#                                    package) and with every lane run to its loop's end (~7 min)
#   bench/gpu_figures.sh gradients   issue 42: forward+backward against forward (B = 1 and 8),
#                                    then the Scorer's clips/s at B = 64 on the same tree (~9 min)
#   bench/gpu_figures.sh host        issue 61: the host's ceiling from disk, every program call replaced
#                                    by a real group's outputs: what the 1,000-clip figure's host allows
#                                    (after reward or pose, whose files in /tmp/corpus it reads) (~3 min)
#   bench/gpu_figures.sh torch       issue 62: TorchScorer against Scorer at B = 64 on cuda:0 (CUDA
#                                    torch beside JAX's CUDA plugin), tensors copied: none (~4 min)
# Each step has its own time limit, so a slow compile loses that step's figure, not the others'.
# bench/README.md has the current figures, bench/history/ those of each lease.
set -o pipefail
OUT=${OUT:-gpu-figures}
mkdir -p "$OUT"
export PYTHONPATH=$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import jax, optimistix; print('jax', jax.__version__, jax.devices(), 'optimistix', optimistix.__version__)"
case "${1:-reward}" in
reward)
    timeout 300 python3 bench/reward.py --batch-sizes 64 1 8 32 --no-baseline --repeats 5 --profile "$OUT/profile" 2>&1 \
        | tee "$OUT/reward.log"
    # B=16 compiles score_batch's group program (16 clips per device) before the disk run reuses it
    timeout 210 python3 bench/reward.py --batch-sizes 16 --no-baseline --repeats 3 --disk-clips 1000 --dir /tmp/corpus 2>&1 \
        | tee "$OUT/disk.log"
    ;;
pose)
    timeout 170 python3 bench/reward.py --batch-sizes 64 --no-baseline --repeats 5 --profile "$OUT/profile" 2>&1 \
        | tee "$OUT/reward.log"
    timeout 200 python3 bench/reward.py --batch-sizes 16 --no-baseline --repeats 3 --disk-clips 1000 --dir /tmp/corpus 2>&1 \
        | tee "$OUT/disk.log"
    timeout 120 python3 bench/normal_equations.py 2>&1 | tee "$OUT/normal_equations.log"
    timeout 60 python3 bench/histogram_copies.py 2>&1 | tee "$OUT/histogram_copies.log"
    ;;
histograms)
    COPIES=${HISTOGRAM_COPIES:-32}
    timeout 60 python3 bench/histogram_copies.py 2>&1 | tee "$OUT/histogram_copies.log"
    for c in 1 "$COPIES"; do
        timeout 190 python3 bench/reward.py --batch-sizes 64 --no-baseline --repeats 5 --histogram-copies "$c" \
            --profile "$OUT/profile-copies$c" 2>&1 | tee "$OUT/reward-copies$c.log"
    done
    ;;
forms)
    timeout 120 python3 bench/normal_equations.py --forms package stacked-unfenced siblings 2>&1 \
        | tee "$OUT/normal_equations.log"
    for form in stacked-unfenced siblings; do
        timeout 180 python3 bench/reward.py --batch-sizes 64 --no-baseline --repeats 5 --linearise "$form" \
            --profile "$OUT/profile-$form" 2>&1 | tee "$OUT/reward-$form.log"
    done
    ;;
widths)
    for pairs in 960 480 240 120 60; do
        timeout 60 python3 bench/normal_equations.py --pairs "$pairs" --forms package 2>&1 \
            | tee "$OUT/normal_equations-$pairs.log"
    done
    ;;
lanes)
    for variant in "" --all-lanes; do
        timeout 200 python3 bench/reward.py --batch-sizes 64 --no-baseline --repeats 5 $variant \
            --profile "$OUT/profile${variant:---left-behind}" 2>&1 | tee "$OUT/reward${variant:---left-behind}.log"
    done
    ;;
host)
    timeout 120 python3 bench/host_ceiling.py --clips 256 --dir /tmp/corpus 2>&1 | tee "$OUT/host_ceiling.log"
    timeout 90 python3 bench/host_ceiling.py --clips 64 --dir /tmp/corpus --repeats 1 --profile 2>&1 \
        | tee "$OUT/host_ceiling-profile.log"
    ;;
gradients)
    timeout 260 python3 bench/gradients.py --batch-size 1 --repeats 5 2>&1 | tee "$OUT/gradients-b1.log"
    timeout 140 python3 bench/reward.py --batch-sizes 64 --no-baseline --repeats 5 2>&1 | tee "$OUT/reward-b64.log"
    timeout 300 python3 bench/gradients.py --batch-size 8 --repeats 3 2>&1 | tee "$OUT/gradients-b8.log"
    ;;
torch)
    python3 -c "import torch; print('torch', torch.__version__, torch.cuda.is_available())"
    timeout 400 python3 bench/torch_bridge.py --batch-size 64 --repeat 10 --device cuda:0 2>&1 | tee "$OUT/torch.log"
    ;;
*)
    echo "usage: bench/gpu_figures.sh [reward|pose|histograms|forms|widths|lanes|gradients|torch]" >&2
    exit 2
    ;;
esac
