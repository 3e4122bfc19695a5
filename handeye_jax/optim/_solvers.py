"""Solvers as configuration objects, kept apart from problems, as optimistix does.

``minimise(fn, solver, bounds, ...)`` runs ``solver`` on ``fn`` inside ``bounds`` and returns a
typed :class:`Solution`. A problem is any JAX-traceable callable of a flat vector ``x`` that
returns a scalar (what DE minimises) and, for Levenberg–Marquardt, has a ``residuals(x)``
method whose squares sum to (about) the same value. Pass an equinox Module so repeated calls
reuse the compiled programs. The solvers know nothing of what the problem computes.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any, Protocol

import equinox as eqx
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray


class Problem(Protocol):
    """What the solvers minimise: ``x ↦ value``; Levenberg–Marquardt also uses ``residuals``."""

    def __call__(self, x: Float[Array, " d"]) -> Float[Array, ""]: ...

    def residuals(self, x: Float[Array, " d"]) -> Float[Array, " r"]: ...


@dataclass(frozen=True, eq=False)
class Bounds:
    """A search box: ``lower < upper``, finite, one entry per parameter (in its unit)."""

    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self):
        lo = np.array(self.lower, dtype=np.float64).reshape(-1)
        hi = np.array(self.upper, dtype=np.float64).reshape(-1)
        if lo.shape != hi.shape:
            raise ValueError(f"bounds differ in length: {lo.shape[0]} and {hi.shape[0]}")
        if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()):
            raise ValueError("bounds must be finite with lower < upper in every parameter")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    @property
    def d(self) -> int:
        return self.lower.shape[0]


@dataclass(frozen=True)
class Solution:
    """What a solver found.

    Attributes:
        x: the best point, ``(d,)``.
        value: the problem's value there.
        steps: generations (DE) or iterations (LM) run.
        evaluations: calls of the problem (DE) or of its residuals and Jacobian (LM).
        converged: the solver's own stopping rule held (not a step limit).
    """

    x: np.ndarray
    value: float
    steps: int
    evaluations: int
    converged: bool


@dataclass(frozen=True)
class DESolution(Solution):
    """A :class:`Solution` of differential evolution, with its final population and history.

    Attributes:
        population, fitness: the final members ``(N, d)`` and their values ``(N,)``.
        best_history: the best value after each generation.
        median_history, median_generations: the population's median value after each chunk of
            generations, and the generations at which it was taken.
    """

    population: np.ndarray | None = None
    fitness: np.ndarray | None = None
    best_history: np.ndarray | None = None
    median_history: np.ndarray | None = None
    median_generations: np.ndarray | None = None


@dataclass(frozen=True)
class LMSolution(Solution):
    """A :class:`Solution` of Levenberg–Marquardt; ``start_value``: the value at ``x0``."""

    start_value: float = float("nan")


class AbstractSolver(eqx.Module):
    """A solver's configuration. Final subclasses implement :meth:`run` only."""

    @abc.abstractmethod
    def run(
        self,
        fn: Problem,
        bounds: Bounds,
        *,
        x0: Float[ArrayLike, " d"] | None,
        key: PRNGKeyArray | None,
        progress: bool,
        desc: str,
    ) -> Solution:
        """Minimise ``fn`` in ``bounds``; see :func:`minimise`."""


def minimise(
    fn: Problem,
    solver: AbstractSolver,
    bounds: Bounds,
    *,
    x0: Float[ArrayLike, " d"] | None = None,
    key: PRNGKeyArray | None = None,
    progress: bool = False,
    desc: str = "",
) -> Any:
    """Minimise ``fn`` inside ``bounds`` with ``solver``.

    Args:
        fn: the problem (see :class:`Problem`).
        solver: e.g. :class:`DifferentialEvolution` or :class:`LevenbergMarquardt`.
        bounds: the search box.
        x0: the start (Levenberg–Marquardt needs one; DE ignores it).
        key: a JAX PRNG key (DE needs one; the same key gives the same run bit for bit).
        progress: show a progress bar on stderr.
        desc: the progress bar's label.
    """
    return solver.run(fn, bounds, x0=x0, key=key, progress=progress, desc=desc)
