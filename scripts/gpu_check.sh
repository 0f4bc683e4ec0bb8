#!/usr/bin/env bash
# The GPU check of evaluator=gpu as ONE prepared run, 8.5 minutes at most, every figure to $OUT:
#   1. the tests marked gpu (tests/evaluators/test_gpu.py: a population in sub-scenes, a split population,
#      racing in rounds of sub-scenes);
#   2. insertion_state's nominal success in GPU sub-scenes (128 trials) against the CPU worker pool's (64), each
#      with its 95% interval;
#   3. trials/s at 512 and 2048 sub-scenes, the CPU pool's beside it (same machine, same run);
#   4. the paper's insertion protocol (10 x 10 x 128, budget=paper) as one red-team run's wall time;
#   then gpu_check.png from the JSONs. A step that fails or runs out of time is recorded and the next runs.
#
# On any machine with a CUDA GPU, in a fresh clone (docs/gpu.md):
#   GRT_TORCH=torch make setup          # .venv with a CUDA build of torch
#   bash scripts/gpu_check.sh           # figures to $OUT (default outputs/gpu_check); commit them under experiments/gpu/
# Without a GPU: the same steps on ManiSkill's CPU simulation at tiny sizes (what can be checked of it):
#   GPU_CHECK_BACKEND=physx_cpu OUT=/tmp/gpu_check bash scripts/gpu_check.sh
# PYTHON=... picks the interpreter (default: the clone's .venv/bin/python, else python3).
set -u
cd "$(dirname "$0")/.."
OUT=${OUT:-outputs/gpu_check}
BACKEND=${GPU_CHECK_BACKEND:-physx_cuda}
if [ -x .venv/bin/python ]; then PY=${PYTHON:-.venv/bin/python}; else PY=${PYTHON:-python3}; fi
WORKERS=${GPU_CHECK_WORKERS:-$(( $(nproc) > 3 ? $(nproc) - 2 : 1 ))}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1

step() {  # step NAME SECONDS COMMAND...: run it under a time limit, log it, record its exit code and seconds
  local name=$1 limit=$2 begin rc
  shift 2
  begin=$(date +%s)
  echo "== $name (at most ${limit} s): $*"
  timeout --kill-after=10 "$limit" "$@" >"$OUT/$name.log" 2>&1
  rc=$?
  printf '{"step": "%s", "exit_code": %d, "seconds": %d, "timed_out": %s}\n' "$name" "$rc" \
    "$(( $(date +%s) - begin ))" "$([ $rc -eq 124 ] || [ $rc -eq 137 ] && echo true || echo false)" >>"$OUT/steps.jsonl"
  tail -n 4 "$OUT/$name.log"
}

{ nvidia-smi || true; } >"$OUT/nvidia-smi.txt" 2>&1
# the imports alone took over 30 s on a loaded 2-core machine: the CPU fallback gives them longer
step versions "$([ "$BACKEND" = physx_cuda ] && echo 30 || echo 90)" "$PY" -c "import numpy, torch, sapien, mani_skill, sys; print(sys.version); print('numpy', numpy.__version__,
'torch', torch.__version__, 'sapien', sapien.__version__, 'mani_skill', mani_skill.__version__, 'cuda',
torch.cuda.is_available(), torch.cuda.get_device_name(0) if torch.cuda.is_available() else '')"

if [ "$BACKEND" = physx_cuda ]; then
  step tests 90 "$PY" -m pytest -q -p no:cacheprovider -m gpu tests/evaluators/test_gpu.py -rA
  step nominal 90 "$PY" -m grt.bench gpu nominal --out "$OUT" --trials 128 --cpu-trials 64 --workers "$WORKERS"
  step throughput 120 "$PY" -m grt.bench gpu throughput --out "$OUT" --sizes 512,2048 --cpu-trials 56 \
    --workers "$WORKERS"
  step protocol 150 "$PY" -m grt.bench gpu protocol --out "$OUT" --timeout 140
else  # the CPU fallback of each step, tiny: one sub-scene per env, a few trials, a smoke budget
  step tests 300 "$PY" -m pytest -q -p no:cacheprovider tests/evaluators/test_gpu.py -rA
  step nominal 300 "$PY" -m grt.bench gpu nominal --backend physx_cpu --out "$OUT" --trials 4 --cpu-trials 4 \
    --workers 1 --max-steps 40
  step throughput 300 "$PY" -m grt.bench gpu throughput --backend physx_cpu --out "$OUT" --sizes 4 --cpu-trials 4 \
    --workers 1 --max-steps 20
  step protocol 400 "$PY" -m grt.bench gpu protocol --backend physx_cpu --out "$OUT" --budget smoke --timeout 390 \
    --overrides "budget.trials=2 budget.population=2 budget.iterations=1 task.session.max_steps=20"
fi
step report 30 "$PY" -m grt.bench gpu report --out "$OUT"
echo "== done: $OUT"; cat "$OUT/steps.jsonl"
