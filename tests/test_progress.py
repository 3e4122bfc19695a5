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
                 progress="test DE")  # fmt: skip
    assert r.converged and r.steps < 5000
    err = capsys.readouterr().err
    last = err.replace("\r", "\n").strip().splitlines()[-1]
    assert f"{r.steps}/{r.steps}" in last and "100%" in last


def test_disabled_bar_prints_nothing(capsys):
    with progress_bar(total=10, desc="x", enabled=False) as bar:
        bar.update(3)
    assert capsys.readouterr().err == ""


def test_a_ctrl_c_while_the_bar_draws_still_ends_its_line(capsys, monkeypatch):
    """A Ctrl-C that lands while tqdm draws the bar's first line (the CLI test sends it as soon
    as "stage 1 DE" appears) used to leave that line open, and the CLI's "interrupted" message
    was printed at its end."""
    import gc
    import signal

    import pytest
    from tqdm import tqdm

    from handeye_jax._core import interrupts

    drawn = tqdm.refresh

    def refresh_then_ctrl_c(self, *args, **kwargs):
        out = drawn(self, *args, **kwargs)
        # gc off while the handler runs, so no gc callback (hypothesis's) runs inside it; the
        # traceback once blamed on this came from execnet's end-of-run SIGINT (conftest.py)
        gc.disable()
        try:
            signal.raise_signal(signal.SIGINT)  # the first draw, inside tqdm's constructor
        finally:
            gc.enable()
        return out

    monkeypatch.setattr(tqdm, "refresh", refresh_then_ctrl_c)
    with interrupts.recording_interrupts(), pytest.raises(KeyboardInterrupt):
        with progress_bar(total=10, desc="stage 1 DE", enabled=True) as bar:
            bar.update(1)
    err = capsys.readouterr().err
    assert "stage 1 DE" in err and err.endswith("\n"), repr(err)
