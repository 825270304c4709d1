#!/usr/bin/env bash
# GPU throughput suite: the benchmark scripts of this folder, sized for one GPU, in one call.
#
#   bash benchmarks/gpu_suite.sh OUTDIR            # full suite (each section under a time limit; 10 min at most)
#   SMOKE=1 bash benchmarks/gpu_suite.sh /tmp/g    # tiny sizes: checks that every section runs (CPU is fine)
#
# Sections (each under its own time limit, so one slow or failing section does not cost the others):
#   1. env_throughput.py: random-action, auto-resetting rollouts of 4,096 to 1,048,576 parallel envs per scenario,
#      highway-env stepped on the same machine's CPU in the same run for the ratio (highway-env must be importable:
#      the README's "Throughput on a GPU" section says how it was installed there); the authors' four scenarios
#      only (--tasks with no names: highway-env's tasks and EnvPool do not fit this section's time limit);
#   2. train_csq.py: merge CSQ, 1 and 32 seeds (a prefix of the authors' 20k steps);
#   3. train_maddpg.py: racetrack CS-MADDPG, 1 / 8 / 32 seeds, plus the update alone and its FLOPs;
#   4. train_onpolicy.py: racetrack, 8 seeds: MAPPO-L and MACPO with the shipped 512 envs per seed, MAPPO-L with
#      8,192 (each program takes 20-40 s to compile, hence so few).
# Every script writes its JSON into OUTDIR; the printed tables end up in OUTDIR/suite.log too.
set -u
out=${1:-benchmarks/results/gpu}
mkdir -p "$out"
cd "$(dirname "$0")/.."
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
py=${PYTHON:-python3}

if [ "${SMOKE:-0}" = 1 ]; then
  ENVS="16 64"; ENV_STEPS=256; HW_S=1; CSQ_STEPS=600; CSQ_SEEDS="1 2"; MAD_STEPS=600; MAD_SEEDS="1 2"
  PPO_SEEDS="1"; PPO_ENVS="64"; LIM="600 600 600 600 600"
else
  ENVS="4096 65536 262144 1048576"; ENV_STEPS=1048576; HW_S=5; CSQ_STEPS=4000; CSQ_SEEDS="1 32"
  MAD_STEPS=3000; MAD_SEEDS="1 8 32"; PPO_SEEDS="8"; PPO_ENVS="8192"; LIM="200 80 120 100 60"
fi

section() {  # name, time limit (s), command...
  local name=$1 limit=$2; shift 2
  echo; echo "=== $name (limit ${limit}s) $(date -u +%H:%M:%S)"
  timeout "$limit" "$@"; local rc=$?
  [ $rc = 0 ] || echo "=== $name: exit code $rc"
}

read -r L_ENV L_CSQ L_MAD L_PPO L_WIDE <<< "$LIM"
{
  echo "=== machine"
  nvidia-smi --query-gpu=name,memory.total,clocks.sm,clocks.max.sm --format=csv 2>/dev/null || echo "no nvidia-smi"
  $py -c "import jax, os; print('jax', jax.__version__, jax.devices(), os.cpu_count(), 'CPUs')"
  section env_throughput $L_ENV $py benchmarks/env_throughput.py --envs $ENVS \
    --env-steps $ENV_STEPS --repeats 3 --highway-seconds $HW_S --tasks --out "$out/env_throughput.json"
  section train_csq $L_CSQ $py benchmarks/train_csq.py --steps $CSQ_STEPS --chunk-steps 2000 \
    --seeds $CSQ_SEEDS --json "$out/train_csq.json"
  section train_maddpg $L_MAD $py benchmarks/train_maddpg.py --steps $MAD_STEPS \
    --chunk-steps 1000 --seeds $MAD_SEEDS --profile --json "$out/train_maddpg.json"
  section train_onpolicy $L_PPO $py benchmarks/train_onpolicy.py --algos mappo-l macpo \
    --scenarios racetrack --seeds $PPO_SEEDS --cycles 2 --repeats 3 --out "$out/train_onpolicy.json"
  section train_onpolicy_wide $L_WIDE $py benchmarks/train_onpolicy.py --algos mappo-l \
    --scenarios racetrack --seeds $PPO_SEEDS --cycles 2 --repeats 3 --num-envs $PPO_ENVS \
    --out "$out/train_onpolicy_wide.json"
  echo "=== done $(date -u +%H:%M:%S)"
} 2>&1 | tee "$out/suite.log"
