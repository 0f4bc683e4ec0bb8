#!/usr/bin/env bash
# Issue 39's benchmark (README.md beside this file): the sweeps, in the order they were run, each resumable
# (the same command again goes on from every run's journal). OUT holds the run folders (not committed);
# collect.py copies their summaries here.
#   bash experiments/search/run.sh grasp 0          # seed 0: per object the baseline, then the four raced searches
#   bash experiments/search/run.sh insertion topdm  # the insertion task: the baseline and one raced search
set -euo pipefail
OUT=${OUT:-outputs/search}
PY=${PY:-python}
OBJECTS=${OBJECTS:-mug,bottle,can,hammer,banana}   # OBJECTS=hammer,banana: only those
case "$1" in
  grasp)
    # one object at a time, all five methods on it, so that a partial sweep compares like with like
    seed=$2
    for object in ${OBJECTS//,/ }; do
      $PY -m grt.run -m experiment=search budget.seed="$seed" object="$object" optimizer=topdm budget.racing=false \
        hydra.sweep.dir="$OUT/grasp/seed$seed/$object/baseline"
      $PY -m grt.run -m experiment=search budget.seed="$seed" object="$object" \
        optimizer=topdm,cma_es,nevergrad,optuna_gp budget.racing=true hydra.sweep.dir="$OUT/grasp/seed$seed/$object/racing"
    done
    ;;
  insertion)
    # the state PPO policy on the USB plug, handles on its grip (the task's regions), budget as above
    common=(experiment=search task=insertion policy=insertion_state selector=manual budget.seed=0,1,2)
    $PY -m grt.run -m "${common[@]}" object=usb_plug optimizer=topdm budget.racing=false \
      hydra.sweep.dir="$OUT/insertion/baseline"
    $PY -m grt.run -m "${common[@]}" object=usb_plug optimizer="$2" budget.racing=true \
      hydra.sweep.dir="$OUT/insertion/racing"
    ;;
  *) echo "usage: run.sh grasp SEED | insertion OPTIMIZER" >&2; exit 2 ;;
esac
