#!/usr/bin/env bash
# The measurements of experiments/maniskill/fidelity/README.md, from the repository root (`make motionplanning`
# once for the planners). Each calibration writes its run folder under outputs/calibrate/fidelity/ and
# collect.py copies calibration.json, fidelity.png and the replayed actions beside this script.
#   bash experiments/maniskill/fidelity/run.sh after      # every shipped ManiSkill task, 32 seeds (+ the replays)
#   bash experiments/maniskill/fidelity/run.sh round      # the round actors' representations (after: 64 vertices, 8 caps)
#   bash experiments/maniskill/fidelity/run.sh hypotheses # why the compound tool parts from the stock one
#   bash experiments/maniskill/fidelity/run.sh friction   # hypotheses.py's tool_friction over 32 seeds (friction_copy.py)
set -u
PY=${PY:-.venv/bin/python}
OUT=outputs/calibrate/fidelity
MP="policy=motion_planner task.session.control_mode=pd_joint_pos"
cal() { local dir=$1; shift; echo "== $dir: $*"; nice -n 10 "$PY" -m grt.calibrate "$@" "hydra.run.dir=$OUT/$dir" 2>&1 | grep -v WARN | tail -12; }
case "${1:-after}" in
  after)
    for t in pull_cube_tool plug_charger place_sphere lift_peg_upright peg_insertion_side; do
      cal "after/$t" task=$t $MP trials=32 fidelity.episodes=4
    done
    for t in pick_cube push_cube pull_cube stack_cube; do
      cal "after/$t" task=$t policy=${t}_expert trials=32 fidelity.episodes=4
    done
    for t in roll_ball poke_cube push_t; do
      cal "after/$t" task=$t '~policy' fidelity.episodes=8
    done ;;
  round)
    for v in "64 0" "255 0" "255 8" "64 16"; do
      set -- $v
      cal "round/place_sphere_h$1_w$2" task=place_sphere $MP trials=32 fidelity.episodes=4 max_hull_vertices=$1 task.session.round_wedges=$2
      cal "round/roll_ball_h$1_w$2" task=roll_ball '~policy' fidelity.episodes=8 max_hull_vertices=$1 task.session.round_wedges=$2
    done ;;
  friction)
    for t in pull_cube_tool plug_charger; do
      PYTHONPATH=$PWD cal "friction/$t" task=$t $MP trials=32 fidelity.episodes=4 \
        task.session.env_module=experiments.maniskill.fidelity.friction_copy
    done ;;
  hypotheses)
    "$PY" experiments/maniskill/fidelity/hypotheses.py --episodes 4 --out experiments/maniskill/fidelity/hypotheses.json ;;
esac
