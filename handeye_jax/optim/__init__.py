"""General-purpose optimisers: they minimise functions of flat vectors and know nothing else.

Solvers are configuration objects kept apart from problems, as in optimistix:
``minimise(fn, solver, bounds, ...)`` returns a typed :class:`Solution`.
"""

from ._box import Box
from ._de import (
    CHUNK_GENERATIONS,
    DifferentialEvolution,
    differential_evolution,
    latin_hypercube,
)
from ._lm import (
    BatchSolution,
    LevenbergMarquardt,
    minimise_batch,
    minimise_starts,
    residuals_and_jacobian,
)
from ._solvers import (
    AbstractSolver,
    Bounds,
    DESolution,
    LMSolution,
    Problem,
    Solution,
    minimise,
)

__all__ = [
    "CHUNK_GENERATIONS",
    "AbstractSolver",
    "BatchSolution",
    "Box",
    "Bounds",
    "DESolution",
    "DifferentialEvolution",
    "LMSolution",
    "LevenbergMarquardt",
    "Problem",
    "Solution",
    "differential_evolution",
    "latin_hypercube",
    "minimise",
    "minimise_batch",
    "minimise_starts",
    "residuals_and_jacobian",
]
