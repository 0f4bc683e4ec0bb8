"""Smoothness-Score budget (paper appendix, lines 649-698)."""

from __future__ import annotations

import numpy as np


def smoothness_score(thetas: np.ndarray, meters_per_unit: float) -> np.ndarray:
    """Mean handle displacement in meters: ``SS(D) = 1/M sum_i ||d_i||``.

    Args:
        thetas: ``(..., H, 3)`` handle displacements in unit-cube units.
        meters_per_unit: the mesh's normalization scale (meters per unit-cube unit).

    Returns:
        ``(...)`` Smoothness Scores in meters.
    """
    return np.linalg.norm(np.asarray(thetas, np.float64), axis=-1).mean(-1) * float(meters_per_unit)


def project_to_budget(thetas: np.ndarray, tau: float | None, meters_per_unit: float) -> np.ndarray:
    """Scale each candidate uniformly onto the budget surface when ``SS > tau`` (``P_tau``).

    Direction-preserving: ``P(D) = s D`` with ``s = min(1, tau / SS(D))``, so ``SS(P(D)) <= tau``.

    Args:
        thetas: ``(..., H, 3)`` unit-cube displacements (not modified).
        tau: budget in meters, or ``None`` for no budget.
        meters_per_unit: the mesh's normalization scale.

    Returns:
        Projected displacements, same shape.
    """
    thetas = np.asarray(thetas, np.float64)
    if tau is None:
        return thetas.copy()
    if not tau > 0:
        raise ValueError(f"the Smoothness-Score budget tau must be > 0 meters, got {tau}")
    ss = smoothness_score(thetas, meters_per_unit)
    scale = np.minimum(1.0, tau / np.maximum(ss, 1e-300))
    return thetas * scale[..., None, None]
