"""hypotheses.py's ``tool_friction`` variant as a task's ``env_module``, so that grt.calibrate scores it over 32 seeds.

Imported in every worker of the command, it gives every convex part of the *swapped* actor friction 0.6 (static
and dynamic; ManiSkill's default material, which the stock actor keeps, is 0.3). The stock side is untouched. An
experiment, not a fix: it asks whether the friction the open-loop replays point at also closes the per-seed gap.

    PYTHONPATH=$PWD .venv/bin/python -m grt.calibrate task=pull_cube_tool policy=motion_planner \\
        task.session.control_mode=pd_joint_pos trials=32 fidelity.episodes=4 \\
        task.session.env_module=experiments.maniskill.fidelity.friction_copy \\
        hydra.run.dir=outputs/calibrate/fidelity/friction/pull_cube_tool
"""

from experiments.maniskill.fidelity.hypotheses import _patch

_patch("tool_friction")
