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


def budget_tau(tau: float | None, tau_rel: float | None, diagonal_m: float) -> tuple[float | None, str]:
    """The Smoothness-Score cap of a run in meters, and a sentence saying where it came from.

    ``tau`` (meters) when given; else ``tau_rel`` x the object's bounding-box diagonal, rounded to 0.1 mm
    (so a relative cap that equals a round absolute one on some object gives exactly that one: 0.087 on
    the mug's 172.6 mm diagonal is the former 15 mm); ``None`` when both are ``None`` (no cap).

    Args:
        tau: ``budget.tau`` in meters or ``None``; tau_rel: ``budget.tau_rel`` or ``None``.
        diagonal_m: the object's bounding-box diagonal in meters.
    """
    if tau is not None:
        return float(tau), f"budget.tau = {tau * 1000:.3g} mm mean handle displacement"
    if tau_rel is None:
        return None, "none (budget.tau and budget.tau_rel are null)"
    meters = round(float(tau_rel) * float(diagonal_m), 4)
    if meters <= 0:
        meters = float(tau_rel) * float(diagonal_m)
    return meters, (f"budget.tau_rel = {tau_rel:g} x the object's {diagonal_m * 1000:.1f} mm diagonal = "
                    f"{meters * 1000:.3g} mm mean handle displacement")
