"""Alias of :mod:`grt.evaluators.sim` for configs saved before the rename (see :mod:`grt.eval`)."""

from grt.evaluators.sim import SimEvaluator

__all__ = ["SimEvaluator"]
