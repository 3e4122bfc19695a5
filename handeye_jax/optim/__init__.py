"""General-purpose optimisers: they minimise functions of flat vectors and know nothing else.

Solvers are configuration objects kept apart from problems, as in optimistix:
``minimise(fn, solver, box, ...)`` returns a typed :class:`Solution` (one family: a
:class:`DESolution`, an :class:`LMSolution`, or a :class:`BatchSolution` of many problems at
once). One box type, :class:`Box`; one DE, the :class:`DifferentialEvolution` solver object.
"""

from ._box import Box
from ._de import CHUNK_GENERATIONS, DifferentialEvolution, latin_hypercube
from ._lm import LevenbergMarquardt, minimise_batch, minimise_starts, residuals_and_jacobian
from ._modes import MAX_MODES, mode_leaders
from ._solvers import (
    AbstractSolver,
    BatchSolution,
    DESolution,
    LMSolution,
    Problem,
    Solution,
    minimise,
)

__all__ = [
    "CHUNK_GENERATIONS",
    "MAX_MODES",
    "AbstractSolver",
    "BatchSolution",
    "Box",
    "DESolution",
    "DifferentialEvolution",
    "LMSolution",
    "LevenbergMarquardt",
    "Problem",
    "Solution",
    "latin_hypercube",
    "minimise",
    "minimise_batch",
    "minimise_starts",
    "mode_leaders",
    "residuals_and_jacobian",
]
