"""What the benchmarks share: the paper data and timing of compiled JAX calls."""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from handeye_jax import HTMModel, vectorise_small_loops
from handeye_jax.optim import _de as de

# As the command line does, before JAX's first computation (handeye_jax._jax._xla says why).
vectorise_small_loops()

PAPER = Path(__file__).resolve().parents[1] / "data" / "paper2023.toml"


def median_ms(fn, reps: int) -> float:
    """Median wall time of ``fn()`` in ms over ``reps`` calls, after one call to compile."""
    jax.block_until_ready(fn())
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3


def interleaved_ms(fns: dict, rounds: int) -> dict[str, list[float]]:
    """Wall times in ms of each ``fns[name]()``, called in turn, round after round.

    Each function is called once first, to compile. Timing the candidates alternately, rather
    than one after the other, lets the machine's slow phases hit all of them alike, so their
    ratios hold even when the absolute times drift.
    """
    for fn in fns.values():
        jax.block_until_ready(fn())
    times = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            times[name].append((time.perf_counter() - t0) * 1e3)
    return times


def de_start(objective, n: int, key: int = 0):
    """A DE run's initial state at population ``n`` in the HTM box, the box, and the settings
    ``optim._de._chunk`` takes after the state: its step (the box, CR 0.9, F 0.5) and its stop
    (no generation limit, early stop off)."""
    lower, upper = (jnp.asarray(b) for b in HTMModel.search_bounds())
    state = de._init(jax.random.PRNGKey(key), lower, upper, n)
    step = de._Step(lower, upper, np.asarray(0.9), np.asarray(0.5))
    # A chunk with no generations to run only evaluates the initial members.
    evaluate = de._Stop(*(np.asarray(v) for v in (0, 0.0, 0.0, False)))
    state = de._chunk(objective, state, step, evaluate)[0]
    stop = de._Stop(*(np.asarray(v) for v in (10**9, 0.0, 0.0, False)))
    return state, lower, upper, (step, stop)


def de_generation_ms(objective, n: int, reps: int, key: int = 0) -> tuple[float, de.DEState]:
    """ms per DE generation at population ``n`` (HTM box), timed over chunks of generations."""
    state, lower, upper, settings = de_start(objective, n, key)
    ms = median_ms(lambda: de._chunk(objective, state, *settings), reps)
    return ms / de.CHUNK_GENERATIONS, state
