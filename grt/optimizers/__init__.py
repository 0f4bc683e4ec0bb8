"""Black-box searches over handle displacements (config group ``optimizer``)."""

from grt.optimizers.base import Optimizer
from grt.optimizers.cem import CEMOptimizer
from grt.optimizers.cma_es import CMAESOptimizer
from grt.optimizers.gaussian import GaussianOptimizer
from grt.optimizers.nevergrad import NevergradOptimizer
from grt.optimizers.optuna_gp import OptunaGPOptimizer
from grt.optimizers.smoothness import project_to_budget, smoothness_score
from grt.optimizers.topdm import TOPDMOptimizer

__all__ = ["Optimizer", "TOPDMOptimizer", "GaussianOptimizer", "CEMOptimizer", "CMAESOptimizer",
           "NevergradOptimizer", "OptunaGPOptimizer",
           "smoothness_score", "project_to_budget"]
