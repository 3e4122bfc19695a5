"""Uncertainty and identifiability from the Jacobian of a stage's error vectors at its optimum.

The residual vector is the per-landmark 2-D error vectors of both terms (``4n`` numbers, mm).
With ``J`` its Jacobian and ``σ² = |e|²/(4n − rank J)``, the parameter covariance is the
Gauss–Newton ``σ²·(JᵀJ)⁺``. The paper's F is a mean of lengths rather than a sum of squares,
so this is the usual linearised estimate, not an exact one; it says which parameters the
data pin down to what precision.

Identifiability is read from the singular values of ``J`` with each column scaled to unit
length (so that mm, deg and scale factors compare). A direction whose singular value is below
:data:`WEAK_RATIO` of the largest is weak: a step along it barely changes any residual. Below
:data:`NULL_RATIO` the data do not determine it at all, and the orthogonal combination (for
two parameters, e.g. ``theta_c1 + gamma_c``) is what the fit can report.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._jax import in_float64
from ._objective import AbstractObjective, errors_of

#: A scaled singular value below this fraction of the largest marks a weak direction.
WEAK_RATIO = 1e-2
#: Below this fraction the direction is not determined by the data at all.
NULL_RATIO = 1e-7
#: Parameters whose share of a unit direction (scaled) exceeds this are named in it.
NAME_SHARE = 0.2


@dataclass(frozen=True)
class WeakDirection:
    """A direction in which the data barely (or never) change the residuals.

    Attributes:
        relative_singular_value: its singular value over the largest (column-scaled).
        params: the parameters it moves (each a share of at least :data:`NAME_SHARE`).
        step: the step along it, in each parameter's unit (its largest component 1).
        rms_change_mm: how much that step changes the 4n residuals, RMS, mm.
        determined: for an undetermined pair of one unit, the combination that is determined
            (``"theta_c1 + gamma_c"``), else ``None``.
        note: the same in words.
    """

    relative_singular_value: float
    params: tuple[str, ...]
    step: dict[str, float]
    rms_change_mm: float
    determined: str | None
    note: str = ""


@dataclass(frozen=True)
class JacobianAnalysis:
    """What the Jacobian of a stage's error vectors at its optimum says (see the module).

    Attributes:
        sigma_mm: the residual standard deviation, mm.
        dof: the degrees of freedom left, ``4n − rank J``.
        std: each parameter's standard deviation in its unit (with a prior, the
            posterior's), ``None`` where the data do not determine it.
        precision: the posterior inverse covariance, ``JᵀJ/σ²`` plus the prior's (what a
            recalibration takes as its prior), rows in the free parameters' order.
        singular_values: of the column-scaled Jacobian, largest first.
        weak_directions: the weak and undetermined directions.
    """

    sigma_mm: float
    dof: int
    std: dict[str, float | None]
    precision: tuple[tuple[float, ...], ...]
    singular_values: tuple[float, ...]
    weak_directions: tuple[WeakDirection, ...]


def error_jacobian(
    objective: AbstractObjective, theta: Float[Array, " d"]
) -> tuple[Float[Array, " r"], Float[Array, "r d"]]:
    """The stacked error vectors ``e`` (mm, ``r = 4n``) and their Jacobian ``∂e/∂theta``."""

    def flat(t):
        errors = errors_of(objective, t)
        return jnp.concatenate([errors.image_vs_tablet.reshape(-1), errors.hand.reshape(-1)])

    return flat(theta), jax.jacfwd(flat)(theta)


def _unit(u: str) -> str:
    return "" if u == "1" else f" {u}"


def _combination(names: Sequence[str], coeffs: np.ndarray) -> str:
    """``a·p + b·q`` with unit coefficients written as bare signs."""
    parts = []
    for name, c in zip(names, coeffs, strict=True):
        mag = "" if abs(abs(c) - 1.0) < 0.02 else f"{abs(c):.3g}·"
        parts.append(f"{'-' if c < 0 else '+'} {mag}{name}")
    text = " ".join(parts)
    return text[2:] if text.startswith("+ ") else "-" + text[2:]


def _sparse_basis(W: np.ndarray) -> list[np.ndarray]:
    """Unit vectors spanning the columns of ``W``, each free of the others' main parameters.

    Singular vectors of near-equal singular values mix freely (xc–βc with yc–αc, say);
    Gauss–Jordan elimination with full pivoting gives a basis in which each vector has its
    own leading parameter and none of the other vectors' leading parameters.
    """
    A = np.array(W.T, dtype=float)  # k × d
    k = A.shape[0]
    pivots: list[int] = []
    for row in range(k):
        sub = np.abs(A[row:])
        sub[:, pivots] = 0.0
        r, c = np.unravel_index(np.argmax(sub), sub.shape)
        A[[row, row + r]] = A[[row + r, row]]
        A[row] /= A[row, c]
        for other in range(k):
            if other != row:
                A[other] -= A[other, c] * A[row]
        pivots.append(int(c))
    return [a / np.linalg.norm(a) for a in A]


def analyse_jacobian(
    errors: np.ndarray,
    jacobian: np.ndarray,
    names: Sequence[str],
    units: Sequence[str],
    depth_mm: np.ndarray | None = None,
    prior_precision: np.ndarray | None = None,
) -> JacobianAnalysis:
    """Standard deviations, singular values and weak directions at an optimum.

    Args:
        errors: the stacked error vectors at the optimum, mm, shape ``(r,)``.
        jacobian: their Jacobian, shape ``(r, d)`` (mm per parameter unit).
        names, units: the parameters' names and units.
        depth_mm: the landmarks' depths, mm, to explain a shift–tilt trade-off (optional).
        prior_precision: the inverse covariance of a Gaussian prior on the parameters,
            ``(d, d)`` (zero rows and columns for those without one), or ``None``.

    Returns:
        The :class:`JacobianAnalysis`.
    """
    errors = np.asarray(errors, dtype=float)
    J = np.asarray(jacobian, dtype=float)
    r, d = J.shape
    if d == 0:  # every parameter held fixed: nothing to analyse
        dof = max(r, 1)
        sigma = float(np.sqrt(np.sum(errors**2) / dof))
        return JacobianAnalysis(sigma, dof, {}, (), (), ())
    col = np.linalg.norm(J, axis=0)
    col = np.where(col > 0, col, 1.0)
    U, s, Vt = np.linalg.svd(J / col, full_matrices=False)
    s_max = s[0] if s[0] > 0 else 1.0
    rel = s / s_max
    rank = int(np.sum(rel > NULL_RATIO))
    dof = max(r - rank, 1)
    sigma = float(np.sqrt(np.sum(errors**2) / dof))

    keep = rel > NULL_RATIO
    V = Vt.T
    cov_scaled = (V[:, keep] / s[keep] ** 2) @ V[:, keep].T
    std = np.sqrt(np.diag(cov_scaled)) * sigma / col
    null_share = np.abs(V[:, ~keep]).max(axis=1) if (~keep).any() else np.zeros(d)
    std_out = {n: (None if null_share[i] > 1e-3 else float(std[i])) for i, n in enumerate(names)}
    precision = (J.T @ J) / sigma**2 if sigma > 0 else np.zeros((d, d))
    if prior_precision is not None:
        # Gauss–Newton with the prior's information added: the posterior of a MAP fit.
        precision = precision + np.asarray(prior_precision, dtype=float)
        std_out = std_of_precision(precision, names)

    null_group = V[:, rel <= NULL_RATIO]
    weak_group = V[:, (rel > NULL_RATIO) & (rel < WEAK_RATIO)]
    scaled = (J, col, s_max)
    weak = tuple(_weak_direction(v, scaled, names, units, depth_mm)
                 for v in [*_sparse_basis(null_group), *_sparse_basis(weak_group)])  # fmt: skip
    rows = tuple(tuple(row) for row in precision.tolist())
    return JacobianAnalysis(sigma, dof, std_out, rows, tuple(float(v) for v in s), weak)


def _weak_direction(
    v: np.ndarray,
    scaled: tuple[np.ndarray, np.ndarray, float],
    names: Sequence[str],
    units: Sequence[str],
    depth_mm: np.ndarray | None,
) -> WeakDirection:
    """The weak direction ``v`` of the column-scaled Jacobian (``scaled``: the Jacobian, its
    column norms and its largest singular value), in parameter units and in words."""
    J, col, s_max = scaled
    rel_k = float(np.linalg.norm((J / col) @ v) / s_max)
    idx = [i for i in np.argsort(-np.abs(v)) if abs(v[i]) >= NAME_SHARE]
    step = v / col  # the direction in parameter units
    step = step / step[idx[0]]
    idx = sorted(idx)
    involved = [names[i] for i in idx]
    # RMS change of the 4n residuals for that step (largest component = 1 unit), mm.
    rms = float(np.linalg.norm(J @ step) / np.sqrt(J.shape[0]))
    step_text = ", ".join(f"{names[i]} {step[i]:+.3g}{_unit(units[i])}" for i in idx)
    determined = None
    if rel_k <= NULL_RATIO:
        if len(idx) == 2 and units[idx[0]] == units[idx[1]]:
            a, b = step[idx[0]], step[idx[1]]
            determined = _combination(involved, np.array([1.0, -a / b]))
            note = (f"{' and '.join(involved)} enter only through {determined}: that is "
                    "determined, each alone is not")  # fmt: skip
        else:
            note = f"not determined: moving ({step_text}) changes no residual"
    else:
        note = (f"{' and '.join(involved)} trade off: the step ({step_text}) changes the "
                f"residuals by only {rms:.3g} mm RMS")  # fmt: skip
        if depth_mm is not None and {"mm", "deg"} <= {units[i] for i in idx}:
            dz = np.asarray(depth_mm, dtype=float)
            note += (f"; all landmarks lie at nearly one depth ({dz.min():.1f}–{dz.max():.1f} "
                     "mm), so a shift and a tilt move them alike")  # fmt: skip
    return WeakDirection(rel_k, tuple(involved), {names[i]: float(step[i]) for i in idx}, rms,
                         determined, note)  # fmt: skip


def std_of_precision(precision: np.ndarray, names: Sequence[str]) -> dict[str, float | None]:
    """Standard deviations from an inverse covariance; ``None`` where it has no information."""
    d = len(names)
    scale = np.sqrt(np.maximum(np.diag(precision), 0.0))
    scale = np.where(scale > 0, scale, 1.0)
    w, V = np.linalg.eigh(precision / np.outer(scale, scale))
    keep = w > NULL_RATIO**2 * max(float(w.max()), 1e-300)
    cov = (V[:, keep] / w[keep]) @ V[:, keep].T / np.outer(scale, scale)
    null = np.abs(V[:, ~keep]).max(axis=1) if (~keep).any() else np.zeros(d)
    return {
        n: (None if null[i] > 1e-3 else float(np.sqrt(max(cov[i, i], 0.0))))
        for i, n in enumerate(names)
    }


@in_float64
def jacobian_diagnostics(
    objective: AbstractObjective,
    theta: Float[Array, " d"],
    names: Sequence[str],
    units: Sequence[str],
    depth_mm: np.ndarray | None = None,
) -> JacobianAnalysis:
    """:func:`analyse_jacobian` of ``objective``'s error vectors at ``theta``."""
    e, J = eqx.filter_jit(error_jacobian)(objective, jnp.asarray(theta))
    return analyse_jacobian(np.asarray(e), np.asarray(J), names, units, depth_mm)
