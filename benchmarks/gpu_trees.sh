#!/bin/bash
# The cuda backend of this tree against another tree's, on one GPU, in one go: what a
# change to the GPU code is judged by (docs/gpu.md, "On an H200"), made for a machine lent
# for a few minutes. From the repository root of the new tree:
#
#   git archive e3e5241 src benchmarks | (mkdir -p /tmp/before && tar -x -C /tmp/before)
#   BEFORE=/tmp/before bash benchmarks/gpu_trees.sh
#
# In order: the device; bench_cuda.py of the tree before, then of this tree (every case, and
# this tree's "extensions-but-cohesion", the case as trees before cohesion ran it); this
# tree's gpu tests; the per-kernel anatomy of both; and while BUDGET lasts a second round of
# benchmarks in the reverse order (the card's clocks drift: before, after, after, before).
# Each stage has a time limit; reports go to OUT, one file a stage.
#
# Environment: BEFORE (a tree with src/ and benchmarks/; none: this tree alone), OUT (default
# gpu-trees), BUDGET (seconds in all, default 540), SITE (a folder put first on PYTHONPATH,
# e.g. packages installed there with `pip install --target`: NumPy and gsd versions that the
# machine's numba-cuda imports with), ANATOMY (0: skip the anatomy), AGAIN (the cases of the
# second round, e.g. "delay small"; default every case).
set -u -o pipefail
export PYTHONUNBUFFERED=1
OUT=${OUT:-gpu-trees}
BUDGET=${BUDGET:-540}
SITE=${SITE:-}
BEFORE=${BEFORE:-}
ANATOMY=${ANATOMY:-1}
AGAIN=${AGAIN:-}
again=()
for c in $AGAIN; do again+=(--case "$c"); done
mkdir -p "$OUT"
T0=$(date +%s)
left() { echo $(( BUDGET - ($(date +%s) - T0) )); }
stage() { echo "=== [$(( $(date +%s) - T0 )) s] $*"; }
# run LIMIT PATH REPORT COMMAND...: COMMAND with PATH (and SITE) first on the Python path, for
# at most LIMIT seconds, its output to the screen and to OUT/REPORT
run() {
    local limit=$1 path=$2 report=$3
    shift 3
    PYTHONPATH="$path${SITE:+:$SITE}" timeout "$limit" "$@" 2>&1 | tee "$OUT/$report"
}

stage "device"
nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv,noheader | tee "$OUT/device.txt"
run 60 src versions.txt python3 -c "import importlib.metadata as m, numpy, gsd.hoomd; from numba import cuda
print(*(p + ' ' + m.version(p) for p in ('numpy', 'numba', 'gsd')), cuda.get_current_device().name)" \
    || exit 3  # no GPU, or packages that do not import together
if [ -n "$BEFORE" ]; then
    stage "bench_cuda.py, the tree before"
    run 160 "$BEFORE/src" bench_before_1.txt python3 "$BEFORE/benchmarks/bench_cuda.py"
fi
stage "bench_cuda.py, this tree"
run 180 src bench_after_1.txt python3 benchmarks/bench_cuda.py
stage "gpu tests"
workers=$(python3 -c "import xdist" 2>/dev/null && echo "-n 8")
run 130 src:tests tests.txt python3 -m pytest -o addopts="" -p no:cacheprovider -q -rfE -m gpu $workers \
    --rootdir . tests/test_cuda.py tests/test_geometry_promises.py
if [ "$ANATOMY" != 0 ]; then
    stage "anatomy"
    run 60 src anatomy_after.txt python3 benchmarks/cuda_anatomy.py --scale 0.3
    if [ -n "$BEFORE" ]; then
        run 60 "$BEFORE/src" anatomy_before.txt python3 "$BEFORE/benchmarks/cuda_anatomy.py" --scale 0.3
    fi
fi
if [ -n "$BEFORE" ] && [ "$(left)" -gt 60 ]; then
    half=$(( ($(left) - 10) / 2 ))
    stage "second round${AGAIN:+ ($AGAIN)}, at most ${half} s a tree"
    run "$half" src bench_after_2.txt python3 benchmarks/bench_cuda.py "${again[@]}"
    run "$half" "$BEFORE/src" bench_before_2.txt python3 "$BEFORE/benchmarks/bench_cuda.py" "${again[@]}"
fi
stage "done"
