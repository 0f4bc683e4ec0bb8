#!/usr/bin/env bash
# The margins table (experiments/margins/README.md): per (task, object, policy) one red-team run whose top 3
# CrashShapes are confirmed on 32 fresh episodes and shrunk (budget.shrink, on by default), then its robustness
# profile (python -m grt.profile run=...; a run that found no CrashShape gets random shapes alone, with the
# same task, policy, object and handles). Each step is skipped when its files exist, and a killed run goes on
# where it stopped: the same command again (a cell that stops, e.g. its folder busy with another process, is
# said and the next one goes on). Run folders go to $OUT (outputs/margins); collect.py copies their
# records here.
#
#   bash experiments/margins/run.sh              # every cell, cheapest first
#   bash experiments/margins/run.sh grasp_mug    # the cells whose name starts with that
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=${PY:-.venv/bin/python}
OUT=${OUT:-outputs/margins}
ONLY=${1:-}
# The search: heuristic (grasp, push) or manual (insertion) handles + TOPDM, 6 x 5 candidates of 8 trials,
# budget=quick's sigma 0.06 and Smoothness-Score cap (0.087 x the object's diagonal), seed 42.
SEARCH=(budget=quick budget.population=6 budget.iterations=5 budget.trials=8 budget.top_k=3
        budget.confirm_trials=32 budget.videos=0)
# A worker silent past a trial's timeout is restarted; on a machine loaded by other work (load 15-18 here) a
# grasp trial outlasted the task's own 200 s and the restarts cost more than the trials: a longer timeout (it
# changes no result) for every command below.
SLOW=${SLOW:-evaluator.trial_timeout=900}
GRASP_SIZES='profile.sizes=[0.5,1,2,4,8,16]'
PLUG_SIZES='profile.sizes=[0.125,0.25,0.5,1,2,4]'
CUBE_SIZES='profile.sizes=[0.25,0.5,1,2,4,8]'

cell() {  # cell NAME "RUN OVERRIDES" "PROFILE OVERRIDES" [SEARCH OVERRIDES]
  local name=$1 run_args=$2 profile_args=$3 dir="$OUT/$1" search=("${SEARCH[@]}")
  [[ $# -ge 4 ]] && read -r -a search <<< "$4"
  [[ -n "$ONLY" && "$name" != "$ONLY"* ]] && return 0
  echo "== $name ($(date -u +%H:%M:%S))"
  if [[ -f "$dir/run_config.yaml" ]]; then  # goes on where it stopped; a finished run: "nothing to do"
    nice -n 5 "$PY" -m grt.run "resume=$dir" "$SLOW" || { echo "   $name: the run stopped (rc $?); the next cell"; return 0; }
  else
    # shellcheck disable=SC2086
    nice -n 5 "$PY" -m grt.run $run_args "${search[@]}" "$SLOW" "hydra.run.dir=$dir" \
      || { echo "   $name: the run stopped (rc $?); the next cell"; return 0; }
  fi
  if compgen -G "$dir/profile/*/profile.json" > /dev/null; then
    echo "   profile done: $(ls -d "$dir"/profile/*/ | tail -1)"
  elif grep -q '"crashshape_found": true' "$dir/summary.json"; then
    # shellcheck disable=SC2086
    nice -n 5 "$PY" -m grt.profile "run=$dir" $profile_args "$SLOW" || echo "   $name: the profile stopped (rc $?)"
  else  # no CrashShape: no adversarial direction; random shapes alone, same task, policy, object and handles
    # shellcheck disable=SC2086
    nice -n 5 "$PY" -m grt.profile $run_args $profile_args "$SLOW" \
      "hydra.run.dir=$dir/profile/random-$(date -u +%Y-%m-%d_%H-%M-%S)" || echo "   $name: the profile stopped (rc $?)"
  fi
}

GRASP_PROFILE="$GRASP_SIZES profile.shapes=3 profile.trials=12"
# The demo (make demo: the mug, the antipodal planner, budget=quick) with its top 3 CrashShapes confirmed on 32
# fresh episodes and shrunk, then its profile with every default (python -m grt.profile run=RUN).
cell demo_mug_antipodal "" "" "budget.confirm_trials=32 budget.videos=0"
cell push_cube_expert   "task=push_cube policy=push_cube_expert"   "$CUBE_SIZES profile.shapes=4 profile.trials=16"
cell push_cube_state    "task=push_cube policy=push_cube_state"    "$CUBE_SIZES profile.shapes=4 profile.trials=16"
cell grasp_mug_antipodal    "object=mug policy=antipodal"       "$GRASP_PROFILE"
cell grasp_mug_contact_graspnet    "object=mug policy=contact_graspnet"    "$GRASP_PROFILE"
cell insertion_plug_state "task=insertion policy=insertion_state selector=manual" "$PLUG_SIZES profile.shapes=4 profile.trials=16"
# The point-cloud policy's profile is reduced (four sizes, 3 shapes x 12 episodes) so that the folder stays
# within about two hours on a loaded 2-core machine.
cell insertion_plug_pcd   "task=insertion policy=insertion_pcd selector=manual" \
  "profile.sizes=[0.5,1,2,4] profile.shapes=3 profile.trials=12"
# A search for the smallest CrashShape (budget.size_penalty=1: the search is told score + S0 x SS / tau) against
# search-then-shrink (the cells above): the same protocol, the smallest confirmed shape of each.
cell grasp_mug_antipodal_size1 "object=mug policy=antipodal budget.size_penalty=1" "$GRASP_PROFILE"
cell insertion_plug_state_size1 "task=insertion policy=insertion_state selector=manual budget.size_penalty=1" \
  "$PLUG_SIZES profile.shapes=4 profile.trials=16"
cell grasp_bottle_antipodal "object=bottle policy=antipodal"    "$GRASP_PROFILE"
cell grasp_can_antipodal    "object=can policy=antipodal"       "$GRASP_PROFILE"
cell grasp_bottle_contact_graspnet "object=bottle policy=contact_graspnet" "$GRASP_PROFILE"
cell grasp_can_contact_graspnet    "object=can policy=contact_graspnet"    "$GRASP_PROFILE"
echo "== all cells done ($(date -u +%H:%M:%S)); collect: python experiments/margins/collect.py $OUT"
