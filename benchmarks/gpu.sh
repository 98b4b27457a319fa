#!/usr/bin/env bash
# Dataset scoring and the differentiable loss on a GPU machine, in one call
# (issues 17 and 18: "measure GPU throughput there and record it").
#
# Usage (on the machine with the GPU, from the repository root):
#   OUT=DIR bash benchmarks/gpu.sh [STEPS]
# STEPS: any of env small rate shard ahead loss batch train (default: env shard,
# about 9 minutes: one device call). The steps' defaults fit two calls:
#   bash benchmarks/gpu.sh env shard             # ~510 s: JAX first run, warm run, HiGHS on every core
#   bash benchmarks/gpu.sh env small loss batch  # ~300 s (add rate: ~90 s more)
# train: benchmarks/train_step.py on configs/full_scale.json (20^3 shapes, the layered
# loss; TRAIN_MESH_DIR, default none: procedural shapes only), 4 steps (TRAIN_S, 300 s).
# ahead: two first runs of the shard, shapes compiled one after the other
# (STABLELEGO_COMPILE_AHEAD=0), then ahead in threads (the default); ~200 s.
# HiGHS on the shard took 272 s on 16 cores of an H200 machine (session 44),
# so a shard run needs most of a call by itself.
#
# Needs the image's python3 with a CUDA jax; packages it lacks (clarabel,
# trimesh) are installed from .whl/ when that folder is there; the shard
# (SHARD, default benchmarks/results/shard1000) and the small set (SMALL,
# default benchmarks/results/small500) of benchmarks/make_shard.py, and a mesh for the loss at .gpu/bunny.ply
# (or MESH=...). Every step runs under its own time limit (seconds:
# SMALL_S, WARM_S, EXACT_S, SHARD_S, SHARD_WARM_S, SHARD_EXACT_S, LOSS_S,
# BATCH_S, RATE_S) and leaves its results files, its
# command's summary line and a line count every 10 s in $OUT/log.txt, so a
# step cut short still says how far it got; everything is packed into
# $OUT/gpu.tgz after each step. Labels and highest scores are compared with
# the HiGHS runs afterwards, on any machine: benchmarks/gpu_compare.py.
#
# JAX runs on the GPU (score's default --jobs: on a GPU, JAX solves in the
# one process that holds it); HiGHS runs with --jobs on every core
# (JAX_PLATFORMS=cpu: its workers never touch the GPU). Each JAX score run
# has its own empty compilation cache (first run) and then reuses it (warm).
set -u
OUT=${OUT:-/tmp/stablelego-gpu}
PY=${PYTHON:-python3}
STEPS=${*:-env shard}
RATE_KEYS=${RATE_KEYS:-dense,8 dense,24 dense,40 layered,20,32}
MESH=${MESH:-.gpu/bunny.ply}
SMALL=${SMALL:-benchmarks/results/small500}
SHARD=${SHARD:-benchmarks/results/shard1000}
JOBS=$(nproc)
R=$(mktemp -d)  # the runs' files; $OUT gets only log.txt and gpu.tgz (a device call brings back few files)
mkdir -p "$R"
LOG=$OUT/log.txt
export PYTHONUNBUFFERED=1
if [ -d .whl ]; then
    $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        && export PYTHONPATH=/tmp/site || exit 1
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
CACHE=$(mktemp -d)

say() { echo "[$(date +%H:%M:%S)] $*" | tee -a "$LOG"; }
pack() { tar -czf "$OUT/gpu.tgz" -C "$R" . 2>/dev/null; }

# score INPUT NAME LIMIT SOLVER [ARGS...]: one score run into $R/NAME.jsonl
score() {
    local input=$1 name=$2 limit=$3 solver=$4
    shift 4
    local out=$R/$name.jsonl
    rm -f "$out"
    say "score $name: $input --solver $solver $* (limit ${limit} s)"
    ( while sleep 10; do say "  $name: $( [ -f "$out" ] && wc -l <"$out" || echo 0) lines"; done ) &
    local watch=$!
    local t0=$(date +%s.%N)
    timeout "$limit" $PY -m stablelego_jax score "$input" --out "$out" --quiet --solver "$solver" "$@" \
        2>"$R/$name.err"
    local rc=$?
    kill $watch 2>/dev/null
    local t1=$(date +%s.%N)
    say "  $name: exit $rc, $(wc -l <"$out" 2>/dev/null || echo 0) lines, $(awk "BEGIN{printf \"%.1f\", $t1 - $t0}") s wall (process)"
    tail -n 2 "$R/$name.err" | tee -a "$LOG"
    pack
}

for step in $STEPS; do
case $step in
env)
    say "env"
    nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.sm,clocks.max.sm --format=csv 2>&1 | tee -a "$LOG"
    $PY -c "import jax, jaxlib, numpy, scipy; print('jax', jax.__version__, 'numpy', numpy.__version__, \
'scipy', scipy.__version__, jax.devices(), jax.default_backend())" 2>&1 | tee -a "$LOG"
    echo "cores $JOBS" | tee -a "$LOG"
    ;;
small)
    export STABLELEGO_CACHE_DIR=$CACHE/small
    score "$SMALL" small_jax_first "${SMALL_S:-110}" jax
    score "$SMALL" small_jax_warm "${WARM_S:-50}" jax
    JAX_PLATFORMS=cpu score "$SMALL" small_exact "${EXACT_S:-30}" exact --jobs "$JOBS"
    ;;
rate)
    say "batch_rate.py: layouts/s at batch 1, 64, 1024 on $RATE_KEYS (limit ${RATE_S:-90} s)"
    timeout "${RATE_S:-90}" $PY benchmarks/batch_rate.py --inputs "$SHARD" --top 0 --keys $RATE_KEYS \
        --sizes 1 64 1024 --seconds 2 --max-gb 60 --json "$R/rate.json" 2>"$R/rate.err" | tee -a "$LOG"
    say "  exit ${PIPESTATUS[0]}"
    pack
    ;;
ahead)
    # the shard's first run with the shapes compiled one after the other, then ahead in threads
    # (batch.compile_ahead, the default on an accelerator), each with its own empty cache
    export STABLELEGO_CACHE_DIR=$CACHE/ahead0
    STABLELEGO_COMPILE_AHEAD=0 score "$SHARD" shard_jax_serial "${SHARD_S:-140}" jax
    export STABLELEGO_CACHE_DIR=$CACHE/ahead1
    score "$SHARD" shard_jax_ahead "${SHARD_S:-140}" jax
    ;;
shard)
    export STABLELEGO_CACHE_DIR=$CACHE/shard
    score "$SHARD" shard_jax_first "${SHARD_S:-140}" jax
    score "$SHARD" shard_jax_warm "${SHARD_WARM_S:-60}" jax
    JAX_PLATFORMS=cpu score "$SHARD" shard_exact "${SHARD_EXACT_S:-300}" exact --jobs "$JOBS"
    ;;
loss)
    say "loss_scale 2000 placements (limit ${LOSS_S:-60} s)"
    timeout "${LOSS_S:-60}" $PY benchmarks/loss_scale.py --mesh "$MESH" --placements 2000 --calls 12 --fd 0 \
        --repeat 2 --json >"$R/loss2000.json" 2>"$R/loss2000.err"
    say "  exit $?: $(cat "$R/loss2000.json")"
    pack
    ;;
batch)
    say "loss_scale --batch 32, 500 placements (limit ${BATCH_S:-50} s)"
    timeout "${BATCH_S:-50}" $PY benchmarks/loss_scale.py --mesh "$MESH" --placements 500 --batch 32 --json \
        >"$R/batch32.json" 2>"$R/batch32.err"
    say "  exit $?: $(cat "$R/batch32.json")"
    pack
    ;;
train)
    say "train_step full_scale, 4 steps (limit ${TRAIN_S:-300} s)"
    timeout "${TRAIN_S:-300}" $PY benchmarks/train_step.py --config stablelego_jax/train/configs/full_scale.json \
        --steps 4 --mesh-dir "${TRAIN_MESH_DIR:-none}" --json >"$R/train_full.json" 2>"$R/train_full.err"
    say "  exit $?: $(cat "$R/train_full.json"; tail -n 4 "$R/train_full.err")"
    pack
    ;;
*)
    say "unknown step $step"
    ;;
esac
done
pack
say "done"
