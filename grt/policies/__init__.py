"""GRT policies: black boxes behind small interfaces (:mod:`grt.policies.base`), picked by ``conf/policy``."""

from grt.policies.base import (
    BatchedPolicy,
    Grasp,
    GraspObservation,
    GraspPolicy,
    GraspPredictor,
    GraspStepPolicy,
    PointCloudGraspPolicy,
)

__all__ = ["BatchedPolicy", "Grasp", "GraspObservation", "GraspPolicy", "GraspPredictor", "GraspStepPolicy",
           "PointCloudGraspPolicy"]
