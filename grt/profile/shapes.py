"""The shapes of a robustness profile: deformations of a given size, random or along a CrashShape's direction.

A shape's **size** is the largest displacement of any point of the surface from the nominal object (mm), the
figure a drawing's tolerance states ("nothing moves by more than 2 mm"). A direction ``u`` (handle
displacements ``(H, 3)``, unit cube) is scaled to a size by a few steps of ``theta <- theta * size / got``: the
deformation is linear in ``theta`` up to the rigid alignment on the anchors, so two or three steps land within
1%.
"""

from __future__ import annotations

import math

import numpy as np

from grt.errors import UserError


class ProfileError(UserError):
    """A profile that cannot be measured as asked (its sizes, its run); the message names the fix."""


def largest_mm(deformer, theta: np.ndarray) -> float:
    """The largest surface displacement (mm) of the shape ``theta`` ``(H, 3)``."""
    moved = deformer.vertices(np.asarray(theta, np.float64)) - np.asarray(deformer.mesh.vertices)
    return float(np.linalg.norm(moved, axis=1).max()) * 1000.0


def scale_to_size(deformer, direction: np.ndarray, size_mm: float, tol: float = 0.01) -> np.ndarray:
    """``direction`` ``(H, 3)`` scaled so that the shape's largest surface displacement is ``size_mm``."""
    direction = np.asarray(direction, np.float64)
    norm = float(np.linalg.norm(direction))
    if not norm > 0:
        raise ValueError("a direction of zero displacements has no size")
    theta = direction * (1e-3 / norm)  # small: the linear regime, for the first estimate
    for _ in range(6):
        got = largest_mm(deformer, theta)
        if abs(got - size_mm) <= tol * size_mm:
            break
        theta = theta * (size_mm / got)
    return theta


def random_direction(rng: np.random.Generator, handles: int) -> np.ndarray:
    """A direction of handle displacements ``(H, 3)`` uniform on the sphere (each coordinate Gaussian)."""
    return rng.standard_normal((handles, 3))


def default_sizes(diagonal_mm: float, tau_mm: float | None, top_mm: float | None = None, count: int = 6) -> list[float]:
    """The default ladder (mm, ascending): ``count`` sizes halving down from its top, rounded to two
    significant digits. The top is ``top_mm`` (the largest CrashShape's size, with a run), else the run's
    Smoothness-Score cap ``tau_mm``, else 8.7% of the object's diagonal (the ``quick`` budget's cap)."""
    top = top_mm or tau_mm or 0.087 * diagonal_mm
    sizes = {float(f"{top / 2 ** k:.2g}") for k in range(count)}
    return sorted(sizes)


def check_sizes(sizes) -> list[float]:
    """The ladder ``profile.sizes`` gives, ascending, or one line saying what is wrong with it.

    Raises:
        ProfileError: empty, not numbers, or a size that is not a positive number of mm.
    """
    if sizes is None:
        raise ProfileError("profile.sizes is null here; give sizes in mm, e.g. profile.sizes=[1,2,4,8]")
    values = list(sizes)
    if not values:
        raise ProfileError("profile.sizes=[] is empty: give the sizes to measure in mm (the largest surface "
                           "displacement), e.g. profile.sizes=[1,2,4,8], or leave it null for the default ladder")
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise ProfileError(f"profile.sizes: {v!r} is not a size: every size is a positive number of mm (the "
                               "largest surface displacement), e.g. profile.sizes=[1,2,4,8]")
    return sorted({float(v) for v in values})


def plausible_shapes(deformer, size_mm: float, count: int, rng: np.random.Generator, validity,
                     draws: int = 20) -> tuple[list[np.ndarray], int]:
    """Up to ``count`` random shapes of ``size_mm`` that ``validity(nominal, mesh)`` accepts, drawing at most
    ``draws`` directions; returns ``(thetas, refused)``."""
    thetas, refused = [], 0
    for _ in range(draws):
        if len(thetas) == count:
            break
        theta = scale_to_size(deformer, random_direction(rng, len(deformer.handles)), size_mm)
        if validity is None or validity(deformer.mesh, deformer.meshes(theta)[0])["valid"]:
            thetas.append(theta)
        else:
            refused += 1
    return thetas, refused


def plausible_limit(deformer, size_mm: float, rng: np.random.Generator, validity, draws: int = 8) -> float | None:
    """About the largest size (mm) below ``size_mm`` at which a random shape passes ``validity``: halving
    until one of ``draws`` does (``None``: none down to 1/256 of it)."""
    size = size_mm
    for _ in range(8):
        size /= 2
        if plausible_shapes(deformer, size, 1, rng, validity, draws)[0]:
            return float(f"{size:.2g}")
    return None
