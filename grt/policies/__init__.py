"""GRT policies: black boxes behind small interfaces (:mod:`grt.policies.base`), picked by ``conf/policy``."""

from grt.policies.base import (
    ClosedLoopPolicy,
    Grasp,
    GraspObservation,
    GraspPolicy,
    GraspPredictor,
    PointCloudGraspPolicy,
)

__all__ = ["ClosedLoopPolicy", "Grasp", "GraspObservation", "GraspPolicy", "GraspPredictor",
           "PointCloudGraspPolicy"]
