"""Solvers as configuration objects, kept apart from problems, as optimistix does.

``minimise(fn, solver, box, ...)`` runs ``solver`` on ``fn`` inside ``box`` and returns its
typed :class:`Solution`. A problem is any JAX-traceable callable of a flat vector ``x`` that
returns a scalar (what DE minimises) and, for Levenberg–Marquardt, has a ``residuals(x)``
method whose squares sum to (about) the same value. Pass an equinox Module so repeated calls
reuse the compiled programs. The solvers know nothing of what the problem computes.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

import equinox as eqx
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from ._box import Box


class Problem(Protocol):
    """What the solvers minimise: ``x ↦ value``; Levenberg–Marquardt also uses ``residuals``."""

    def __call__(self, x: Float[Array, " d"]) -> Float[Array, ""]: ...

    def residuals(self, x: Float[Array, " d"]) -> Float[Array, " r"]: ...


@dataclass(frozen=True)
class Solution:
    """What a solver found; every solver returns one of this family.

    Attributes:
        x: the best point, ``(d,)`` (a batch: each problem's, ``(B, d)``).
        value: the problem's value there (a batch: each problem's ``|r|²``, ``(B,)``, ``inf``
            where its residuals were not finite).
        steps: generations (DE) or iterations (LM) run.
        evaluations: calls of the problem (DE) or of its residuals and Jacobian (LM).
        converged: the solver's own stopping rule held (not a step limit).
    """

    x: np.ndarray
    value: float | np.ndarray
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


@dataclass(frozen=True)
class BatchSolution(Solution):
    """A :class:`Solution` of many problems solved at once (:func:`minimise_batch`): ``x``
    ``(B, d)`` and ``value``, each problem's ``|r|²`` ``(B,)``."""


#: The Solution a solver returns.
S = TypeVar("S", bound="Solution", covariant=True)


class AbstractSolver(eqx.Module, Generic[S]):
    """A solver's configuration. Final subclasses implement :meth:`run` only; ``S`` is the
    :class:`Solution` they return."""

    @abc.abstractmethod
    def run(
        self,
        fn: Problem,
        box: Box,
        *,
        x0: Float[ArrayLike, " d"] | None,
        key: PRNGKeyArray | None,
        progress: bool | str,
    ) -> S:
        """Minimise ``fn`` in ``box``; see :func:`minimise`."""


def minimise(
    fn: Problem,
    solver: AbstractSolver[S],
    box: Box,
    *,
    x0: Float[ArrayLike, " d"] | None = None,
    key: PRNGKeyArray | None = None,
    progress: bool | str = False,
) -> S:
    """Minimise ``fn`` inside ``box`` with ``solver``: its :class:`Solution`.

    Args:
        fn: the problem (see :class:`Problem`).
        solver: e.g. :class:`DifferentialEvolution` (a :class:`DESolution`) or
            :class:`LevenbergMarquardt` (an :class:`LMSolution`).
        box: the search box.
        x0: the start (Levenberg–Marquardt needs one; DE ignores it).
        key: a JAX PRNG key (DE needs one; the same key gives the same run bit for bit).
        progress: show a progress bar on stderr (a string: with that label).
    """
    if np.ndim(box.lower) != 1:
        raise ValueError("one problem needs one box: bounds of shape (d,), not a batch")
    return solver.run(fn, box, x0=x0, key=key, progress=progress)
