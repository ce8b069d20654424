#!/usr/bin/env bash
# The whole GPU comparison of issue 40 in one go (softreach and hj_reachability, every row) on one H100 or H200: the
# per-row limits add up to 8.2 minutes. It prints the device, the CUDA kernels against the CPU loops
# (gpu_check.py), then one table per row (bench_solver.py: whole `softreach solve` process against the peer's solve,
# same accuracy preset, horizon and projection; cold = empty compile caches, warm = from them).
#
# The lent machine's python3 holds CUDA torch, JAX, numba and numba-cuda; nothing can be fetched there. Carry the
# wheels it lacks in .whl/, made here by
# `pip download --no-deps --only-binary=:all: --python-version 3.12 -d .whl hj-reachability==0.7.0 gymnasium==1.4.0
# farama-notifications stable-baselines3==2.9.2`, and send a frozen copy so that uncommitted edits cannot travel:
#
#     mkdir -p .snap && git archive HEAD | tar -x -C .snap && rm .snap/reach/proof/cells/*.npz && cp -r .whl .snap/   # .snap ignored
#     run tool: `cd .snap && bash benchmarks/gpu_compare.sh 2>&1 | tee $OUT/all.log`, carry [".snap"], timeout_s 540
#
# Each row has its own time limit, so that one slow row cannot take the others with it. Per-row logs go to
# $GPU_LOG (default /tmp/gpu_compare) as well as to the terminal.
set -u
export PYTHONUNBUFFERED=1
LOG=${GPU_LOG:-/tmp/gpu_compare}
mkdir -p "$LOG"
PY=${PYTHON:-python3}

. benchmarks/gpu_setup.sh
CACHE=/tmp/softreach-gpu-cache   # one cache for every row: the first row of each shape is the cold one
rm -rf "$CACHE"

{
  date -u; nvidia-smi -L
  $PY - <<'EOF'
import time, torch
print("torch", torch.__version__, "device", torch.cuda.get_device_name(0))
x = torch.empty(2**28, device="cuda"); y = torch.empty_like(x); y.copy_(x); torch.cuda.synchronize()
t0 = time.perf_counter()
for _ in range(10):
    y.copy_(x)
torch.cuda.synchronize()
print(f"device copy: {2 * x.numel() * 4 * 10 / (time.perf_counter() - t0) / 1e12:.2f} TB/s (read + written)")
try:
    import jax, hj_reachability
    print("peer: hj_reachability", hj_reachability.__version__, "jax", jax.__version__, jax.devices())
except Exception as exc:
    print("peer unavailable:", exc)
EOF
} 2>&1 | tee "$LOG/device.txt"

# the CUDA kernels against the CPU loops, and the stepping of the paper grid alone
echo "=== gpu_check ($(date -u +%T))"
# (the rows need the kernels: where they fail, stop here and keep the rest of a short loan for a second try)
set -o pipefail
timeout 90 env SOFTREACH_CACHE=$CACHE/check $PY benchmarks/gpu_check.py 2>&1 | tee "$LOG/gpu_check.txt" \
  || { echo "!!! gpu_check: failed or over 90 s; no rows run"; exit 1; }
set +o pipefail

B="$PY benchmarks/bench_solver.py --device cuda --peer-python $PY --threads 1 --cache-dir $CACHE --accuracy very_high"
row() {  # row NAME SECONDS ARGS...; the GPU memory in use (every process, CUDA contexts included) sampled meanwhile
  local name=$1 limit=$2; shift 2
  echo "=== $name ($(date -u +%T))"
  nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits -lms 100 >"$LOG/$name.mem" 2>/dev/null &
  local smi=$!
  timeout "$limit" $B "$@" 2>&1 | tee "$LOG/$name.txt" || echo "!!! $name: failed or over ${limit} s"
  kill $smi 2>/dev/null; wait $smi 2>/dev/null
  echo "$name: most GPU memory in use while it ran (nvidia-smi, every process): $(sort -n "$LOG/$name.mem" | tail -1) MiB"
}
row pointmass_W_101 90 --grid 101 101 --budget-points 111           # cold + warm + peer
row pointmass_V_101 40 --grid 101 101 --game V --no-cold             # V compiled by the row above
row paper_W_300 110 --grid 300 300 --budget-points 200               # cold + warm + peer
row paper_V_300 40 --grid 300 300 --game V --no-cold

# the glider: softreach only (the peer has no model of it), whole process, warm after one cold run of each
for what in W V; do
  extra=$([ $what = V ] && echo --classical)
  for run in cold warm; do
    t0=$(date +%s.%N)
    timeout 30 env SOFTREACH_CACHE=$CACHE/cache TRITON_CACHE_DIR=$CACHE/triton \
      $PY -m softreach.cli solve glider --device cuda --quiet --no-resume --out /tmp/glider.srt $extra \
      >"$LOG/glider_${what}_${run}.txt" 2>&1 || echo "!!! glider $what $run failed"
    echo "glider default $what ($run): $(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN{printf "%.1f", b - a}') s whole process" \
      | tee -a "$LOG/glider.txt"
  done
done
date -u
