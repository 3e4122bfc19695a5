"""The distinct optima in a population: the members that lead the basins it has settled in.

A multi-start search restarts LM from them (:mod:`handeye_jax.calibration`), and the
diagnostics report them. Generic: it knows points, values and a box, nothing else.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from jaxtyping import Float, Int

#: Population members closer than this to a better member, in every parameter (as a fraction
#: of its search range), belong to its optimum.
MODE_RADIUS = 0.05
#: At most this many optima are taken from a population (restarts) or reported, best first.
MAX_MODES = 5


def mode_leaders(
    population: Float[np.ndarray, "n d"],
    fitness: Float[np.ndarray, " n"],
    lower: Float[np.ndarray, " d"],
    upper: Float[np.ndarray, " d"],
    names: Sequence[str] = (),
    flat_steps: Sequence[dict[str, float]] = (),
) -> tuple[Float[np.ndarray, "k d"], Float[np.ndarray, " k"], Int[np.ndarray, " k"]]:
    """The best member of each distinct optimum in a population, best first.

    Members are grouped greedily in order of fitness: a member within :data:`MODE_RADIUS` of
    a group's best member in every parameter (as a fraction of its range) joins that group.
    Non-finite fitnesses are left out.

    Args:
        population, fitness: the population ``(N, d)`` and its values.
        lower, upper: the search box.
        names, flat_steps: parameter names, and directions along which the value barely or
            never changes (``{name: step}``); members apart only along them are one optimum.

    Returns:
        ``(x, value, members)``: each optimum's best member ``(k, d)``, its value ``(k,)`` and
        how many members the group holds ``(k,)``.
    """
    ok = np.isfinite(fitness)
    pop, f = np.asarray(population)[ok], np.asarray(fitness)[ok]
    order = np.argsort(f, kind="stable")
    pop, f = pop[order], f[order]
    width = np.asarray(upper) - np.asarray(lower)
    u = (pop - lower) / width
    if flat_steps:
        V = np.array([[st.get(n, 0.0) for n in names] for st in flat_steps]) / width
        Q, _ = np.linalg.qr(V.T)  # orthonormal basis of the flat directions
        u = u - (u @ Q) @ Q.T
    leaders: list[int] = []
    counts: list[int] = []
    for i in range(len(f)):
        if leaders:
            dist = np.abs(u[leaders] - u[i]).max(axis=1)
            j = int(np.argmin(dist))
            if dist[j] < MODE_RADIUS:
                counts[j] += 1
                continue
        leaders.append(i)
        counts.append(1)
    return pop[leaders], f[leaders], np.array(counts, dtype=int)
