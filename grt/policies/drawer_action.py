"""The drawer task's action and grasp conventions for the Panda, one place for the env and the policies.

``GRT-Drawer-v1`` (:mod:`grt.tasks.drawer_env`) applies them; an analytic policy
(:class:`grt.policies.drawer_expert.DrawerExpertPolicy`) plans with them. They sit at the policies' level
so that a policy needs nothing from the task package above it.
"""

from __future__ import annotations

import numpy as np

ARM_DELTA = 0.1       # rad per control step and unit action (PD: 1 rad/s at |a| = 1)
FINGER_DELTA = 0.015  # m per control step and unit action (a held "close" squeezes with 15 N)
# TCP orientation for a grasp of a horizontal bar: approach (TCP z) towards the drawer (world +x),
# pitched 20 deg down (keeps the Panda's wrist joint 6 clear of its limit), fingers (TCP y) closing in
# the vertical plane across the bar.
GRASP_PITCH = np.deg2rad(20.0)
GRASP_ROT = np.array([[0.0, np.sin(GRASP_PITCH), np.cos(GRASP_PITCH)], [1.0, 0.0, 0.0],
                      [0.0, np.cos(GRASP_PITCH), -np.sin(GRASP_PITCH)]])
APPROACH = GRASP_ROT[:, 2]
