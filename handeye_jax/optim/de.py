"""Differential evolution, DE/rand/1/bin, as a jitted ``lax.scan`` over a vmapped population.

It minimises any function ``fn: Float[Array, "d"] -> Float[Array, ""]`` inside a box; it knows
nothing about what ``fn`` computes. Choices, each documented where a user could doubt it:

* **Index draws in O(1) per member.** r1, r2, r3 are drawn from ``N − 1``, ``N − 2`` and
  ``N − 3`` values and shifted past the indices already taken (in ascending order), which gives
  three indices distinct from each other and from the target without an O(N) choice.
* **Bounds.** A trial component outside ``[lower, upper]`` is replaced by the midpoint between
  the base vector's component (``x_r1``, always inside) and the bound it crossed. This keeps
  the search direction, needs no extra random numbers, and never leaves the box.
* **Initial population.** Latin hypercube sampling of the box, as scipy does by default.
* **Determinism.** Generation ``g`` draws from ``fold_in(key, g)``, so a seed gives the same
  result bit for bit however the run is split into chunks.
* **Early stop.** A generation whose fitness spread satisfies
  ``std(f) <= atol + tol·|mean(f)|`` (scipy's rule) ends the run; ``early_stop=False`` runs
  all generations.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray

from ..progress import progress_bar

#: Generations run per jitted call; the progress bar advances once per chunk.
CHUNK_GENERATIONS = 64


class DEState(eqx.Module):
    population: Float[Array, "n d"]
    fitness: Float[Array, " n"]
    generation: Int[Array, ""]
    converged: Bool[Array, ""]


@dataclass(frozen=True)
class DEResult:
    """Outcome of :func:`differential_evolution`.

    Attributes:
        x: best member found.
        f: its fitness.
        population, fitness: the final population and fitnesses.
        generations: generations run (excluding the initial population).
        evaluations: calls of ``fn``, counting the initial population.
        converged: whether the spread criterion stopped the run.
        best_history, median_history: best and median fitness after each generation.
    """

    x: np.ndarray
    f: float
    population: np.ndarray
    fitness: np.ndarray
    generations: int
    evaluations: int
    converged: bool
    best_history: np.ndarray
    median_history: np.ndarray


def _safe(f: Float[Array, "*n"]) -> Float[Array, "*n"]:
    return jnp.where(jnp.isnan(f), jnp.inf, f)


def latin_hypercube(
    key: PRNGKeyArray, n: int, lower: Float[Array, " d"], upper: Float[Array, " d"]
) -> Float[Array, "n d"]:
    """``n`` points in the box, one per stratum in every dimension."""
    d = lower.shape[0]
    k_perm, k_jit = jax.random.split(key)
    perms = jax.vmap(lambda k: jax.random.permutation(k, n))(jax.random.split(k_perm, d)).T
    u = (perms + jax.random.uniform(k_jit, (n, d), dtype=lower.dtype)) / n
    return lower + u * (upper - lower)


def distinct_indices(key: PRNGKeyArray, n: int) -> Int[Array, "3 n"]:
    """For each member i, three indices distinct from each other and from i, in O(1) each."""
    k1, k2, k3 = jax.random.split(key, 3)
    i = jnp.arange(n)
    r1 = jax.random.randint(k1, (n,), 0, n - 1)
    r1 = r1 + (r1 >= i)
    lo, hi = jnp.minimum(i, r1), jnp.maximum(i, r1)
    r2 = jax.random.randint(k2, (n,), 0, n - 2)
    r2 = r2 + (r2 >= lo)
    r2 = r2 + (r2 >= hi)
    taken = jnp.sort(jnp.stack([i, r1, r2]), axis=0)
    r3 = jax.random.randint(k3, (n,), 0, n - 3)
    for s in taken:
        r3 = r3 + (r3 >= s)
    return jnp.stack([r1, r2, r3])


def _generation(
    fn: Callable,
    state: DEState,
    key: PRNGKeyArray,
    lower: Float[Array, " d"],
    upper: Float[Array, " d"],
    crossover: float,
    mutation: float,
) -> DEState:
    pop = state.population
    n, d = pop.shape
    k_idx, k_cross, k_j = jax.random.split(jax.random.fold_in(key, state.generation), 3)
    r1, r2, r3 = distinct_indices(k_idx, n)
    base = pop[r1]
    mutant = base + mutation * (pop[r2] - pop[r3])
    cross = jax.random.uniform(k_cross, (n, d), dtype=pop.dtype) < crossover
    j_rand = jax.random.randint(k_j, (n,), 0, d)
    cross = cross | (jnp.arange(d)[None, :] == j_rand[:, None])
    trial = jnp.where(cross, mutant, pop)
    trial = jnp.where(trial < lower, 0.5 * (base + lower), trial)
    trial = jnp.where(trial > upper, 0.5 * (base + upper), trial)
    f_trial = _safe(jax.vmap(fn)(trial))
    better = f_trial <= state.fitness
    return DEState(
        population=jnp.where(better[:, None], trial, pop),
        fitness=jnp.where(better, f_trial, state.fitness),
        generation=state.generation + 1,
        converged=state.converged,
    )


def _spread_converged(f: Float[Array, " n"], tol: float, atol: float) -> Bool[Array, ""]:
    return jnp.std(f) <= atol + tol * jnp.abs(jnp.mean(f))


@eqx.filter_jit
def _init(fn, key, lower, upper, n):
    pop = latin_hypercube(key, n, lower, upper)
    return DEState(
        population=pop,
        fitness=_safe(jax.vmap(fn)(pop)),
        generation=jnp.asarray(0),
        converged=jnp.asarray(False),
    )


@eqx.filter_jit
def _chunk(fn, state, key, lower, upper, max_generations, crossover, mutation, tol, atol, stop):
    def step(state, _):
        active = (~state.converged) & (state.generation < max_generations)
        state = jax.lax.cond(
            active,
            lambda s: _generation(fn, s, key, lower, upper, crossover, mutation),
            lambda s: s,
            state,
        )
        converged = state.converged | (stop & active & _spread_converged(state.fitness, tol, atol))
        state = eqx.tree_at(lambda s: s.converged, state, converged)
        return state, (jnp.min(state.fitness), jnp.median(state.fitness), active)

    return jax.lax.scan(step, state, None, length=CHUNK_GENERATIONS)


def differential_evolution(
    fn: Callable[[Float[Array, " d"]], Float[Array, ""]],
    lower: Float[ArrayLike, " d"],
    upper: Float[ArrayLike, " d"],
    *,
    key: PRNGKeyArray,
    population: int,
    generations: int,
    crossover: float = 0.9,
    mutation: float = 0.5,
    tol: float = 1e-6,
    atol: float = 0.0,
    early_stop: bool = True,
    progress: bool = False,
    desc: str = "DE",
) -> DEResult:
    """Minimise ``fn`` over the box ``[lower, upper]`` with DE/rand/1/bin.

    Args:
        fn: the objective; a JAX-traceable function of one parameter vector. Pass an equinox
            Module (or another pytree-callable) so repeated calls reuse the compiled code.
        lower, upper: the box, one entry per parameter, ``lower < upper``.
        key: PRNG key; the same key gives the same run bit for bit.
        population: N, the number of members (≥ 4).
        generations: G, the most generations to run.
        crossover: CR, the binomial crossover probability.
        mutation: F, the differential weight.
        tol, atol: the early-stop spread criterion (see the module docstring).
        early_stop: stop when the spread criterion holds; False runs all G generations.
        progress: show a tqdm progress bar on stderr.
        desc: the progress bar's label.
    """
    if population < 4:
        raise ValueError(f"population must be at least 4 for DE/rand/1 (got {population})")
    lower = jnp.asarray(lower, dtype=float)
    upper = jnp.asarray(upper, dtype=float)
    k_init, k_run = jax.random.split(key)
    state = _init(fn, k_init, lower, upper, population)
    best, median = [], []
    with progress_bar(total=generations, desc=desc, enabled=progress, unit="gen") as bar:
        while True:
            state, (b, m, active) = _chunk(
                fn, state, k_run, lower, upper, generations, crossover, mutation,
                tol, atol, early_stop,
            )  # fmt: skip
            active = np.asarray(active)
            best.append(np.asarray(b)[active])
            median.append(np.asarray(m)[active])
            bar.update(int(active.sum()))
            if bool(state.converged) or int(state.generation) >= generations:
                break
    fitness = np.asarray(state.fitness)
    i_best = int(np.argmin(fitness))
    n_gen = int(state.generation)
    return DEResult(
        x=np.asarray(state.population[i_best]),
        f=float(fitness[i_best]),
        population=np.asarray(state.population),
        fitness=fitness,
        generations=n_gen,
        evaluations=population * (n_gen + 1),
        converged=bool(state.converged),
        best_history=np.concatenate(best),
        median_history=np.concatenate(median),
    )
