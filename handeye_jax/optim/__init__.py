"""General-purpose optimisers: they minimise functions of flat vectors and know nothing else.

Solvers are configuration objects kept apart from problems, as in optimistix:
``minimise(fn, solver, box, ...)`` returns a typed :class:`Solution` (one family: a
:class:`DESolution`, an :class:`LMSolution`, or a :class:`BatchSolution` of many starts at
once). One box type, :class:`Box`; one DE, the :class:`DifferentialEvolution` solver object.
``minimise_many(fns, solver, box, ...)`` runs a solver on a batch of problems, each with its
own box (a :class:`Box` of ``(b, d)`` bounds) and stopping rule and each giving its own run's
numbers bit for bit, the batch sharded over the devices; it returns the same Solution with a
leading axis of problems (:func:`take` picks one).
"""

from ._box import Box
from ._de import CHUNK_GENERATIONS, DifferentialEvolution, latin_hypercube
from ._lm import LevenbergMarquardt, minimise_batch, residuals_and_jacobian
from ._many import LOOPED, minimise_many, minimise_starts_many, take, values_many
from ._modes import MAX_MODES, mode_leaders
from ._multistart import minimise_starts
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
    "LOOPED",
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
    "minimise_many",
    "minimise_starts",
    "minimise_starts_many",
    "mode_leaders",
    "residuals_and_jacobian",
    "take",
    "values_many",
]
