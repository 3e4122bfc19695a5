"""Progress bars: shown on request, and never left half-drawn by an early stop."""

import equinox as eqx
import jax
import jax.numpy as jnp

from handeye_jax._core import progress_bar
from handeye_jax.optim import Box, DifferentialEvolution, minimise


class Sphere(eqx.Module):
    def __call__(self, x):
        return jnp.sum(x**2)


def test_early_stop_closes_a_complete_bar(capsys):
    de = DifferentialEvolution(population=30, generations=5000, tol=1e-3)
    r = minimise(Sphere(), de, Box([-1.0] * 3, [1.0] * 3), key=jax.random.PRNGKey(0),
                 progress=True, desc="test DE")  # fmt: skip
    assert r.converged and r.steps < 5000
    err = capsys.readouterr().err
    last = err.replace("\r", "\n").strip().splitlines()[-1]
    assert f"{r.steps}/{r.steps}" in last and "100%" in last


def test_disabled_bar_prints_nothing(capsys):
    with progress_bar(total=10, desc="x", enabled=False) as bar:
        bar.update(3)
    assert capsys.readouterr().err == ""
