"""The small compiled programs a fit evaluates with, one per job, so that each stage compiles
each once (not one for F and one for the residuals)."""

from __future__ import annotations

import jax
import numpy as np

from .._jax import fast_compile
from ..optim import (
    latin_hypercube,
)
from ..problem import (
    AbstractObjective,
    chain_points,
    error_jacobian,
    errors_of,
    fitness,
    norms,
    stage2_errors,
)


@fast_compile
def _report(objective: AbstractObjective, x):
    # Every evaluation of a stage's objective outside the optimisers goes through this one
    # program, so each stage compiles one (not one for F and one for the residuals).
    errors = errors_of(objective, x)
    return errors, fitness(errors), norms(errors), objective(x), objective.terms(x)


def _value(objective: AbstractObjective, x) -> float:
    """The value the optimisers minimise at ``x`` (the paper's F without loss or prior)."""
    return float(_report(objective, np.asarray(x))[3])


@fast_compile
def _stage_keys(seed):
    # One small program, where PRNGKey, split and unpacking would compile several. Each stage
    # gets the DE's key and, folded from it, the key of its LM restarts.
    key1, key2 = jax.random.split(jax.random.PRNGKey(seed))
    return (key1, jax.random.fold_in(key1, 1)), (key2, jax.random.fold_in(key2, 1))


_lhs = fast_compile(latin_hypercube)


@fast_compile
def _points(model, obs):
    return chain_points(model, obs)


@fast_compile
def _centres(correction, points, centre_index: int):
    return stage2_errors(correction, points, centre_index)[1]


@fast_compile
def _error_jacobian(objective, x):
    return error_jacobian(objective, x)
