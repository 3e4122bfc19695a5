"""Serialized programs (issue 19, section 3): a later process loads a stored program instead of
tracing it, gets the same numbers bit for bit, and a stale or damaged file is rebuilt."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import handeye_jax._jax._xla as _xla
from handeye_jax.optim import Box, DifferentialEvolution, LevenbergMarquardt, minimise

TRACES = {"n": 0}


def _rosenbrock(x):
    TRACES["n"] += 1  # Python runs only while JAX traces
    r = jnp.stack([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0], 0.5 * (x[2] - 0.3)])
    return r


class Problem(eqx.Module):
    """A least-squares problem (sum of squared residuals) with a known minimum, (1, 1, 0.3)."""

    def __call__(self, x):
        return jnp.sum(_rosenbrock(x) ** 2)

    def residuals(self, x):
        return _rosenbrock(x)


BOUNDS = Box(np.array([-2.0, -2.0, -2.0]), np.array([2.0, 3.0, 2.0]))
DE = DifferentialEvolution(population=24, generations=40, early_stop=False)
LM = LevenbergMarquardt(rtol=1e-12, atol=0.0, max_steps=200)


def _solve():
    with jax.enable_x64(True):
        de = minimise(Problem(), DE, BOUNDS, key=jax.random.PRNGKey(3))
        lm = minimise(Problem(), LM, BOUNDS, x0=np.asarray(de.x))
        return np.asarray(de.population), np.asarray(de.x), np.asarray(lm.x), float(lm.value)


@pytest.fixture
def store(tmp_path):
    folder = tmp_path / "programs"
    suites = _xla._store.folder  # the suite's own store (tests/conftest.py), put back after
    yield folder
    _xla.store_programs(None)
    _xla.store_programs(suites)


def _as_a_new_process(store):
    """Nothing in memory, the files on disk (the same folder again keeps what is loaded)."""
    _xla.store_programs(None)
    _xla.store_programs(store)


def _same(a, b):
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


def test_a_stored_program_is_loaded_without_tracing_and_gives_the_same_numbers(store):
    plain = _solve()  # no store: JAX's usual jit
    np.testing.assert_allclose(plain[2], [1.0, 1.0, 0.3], atol=1e-6)
    _xla.store_programs(store)
    built = _solve()
    files = sorted(store.glob("*.program"))
    assert len(files) >= 3  # the DE's start and loop, and the LM
    _as_a_new_process(store)
    before = TRACES["n"]
    loaded = _solve()
    assert TRACES["n"] == before  # the problem was not traced again
    _same(plain, built)
    _same(plain, loaded)


def test_the_same_folder_again_keeps_what_this_process_loaded(store):
    """Each command run in one process turns the store on again: it must not drop and reload
    every program (in-process commands of the suite, the notebooks, a user's script)."""
    _xla.store_programs(store)
    want = _solve()
    for f in store.glob("*.program"):
        f.unlink()
    _xla.store_programs(store)
    before = TRACES["n"]
    _same(_solve(), want)
    assert TRACES["n"] == before  # neither traced again
    assert not list(store.glob("*.program"))  # nor rebuilt from the (now empty) folder


@pytest.mark.parametrize("damage", ["truncated", "garbage", "another program", "empty"])
def test_a_damaged_or_stale_program_is_rebuilt_with_the_same_numbers(store, damage):
    _xla.store_programs(store)
    want = _solve()
    files = sorted(store.glob("*.program"))
    contents = {f: f.read_bytes() for f in files}
    damaged = {}
    for i, f in enumerate(files):
        data = contents[f]
        damaged[f] = {
            "truncated": data[: len(data) // 2],
            "garbage": data[:200] + bytes(range(256)) * 4,
            "another program": contents[files[(i + 1) % len(files)]],  # e.g. another JAX's
            "empty": b"",
        }[damage]  # fmt: skip
        f.write_bytes(damaged[f])
    _as_a_new_process(store)
    before = TRACES["n"]
    _same(_solve(), want)
    assert TRACES["n"] > before  # rebuilt: traced again
    for f in files:  # and stored again, whole
        data = f.read_bytes()
        assert data != damaged[f] and data.startswith(_xla.FORMAT) and len(data) > 1000
    _as_a_new_process(store)
    before = TRACES["n"]
    _same(_solve(), want)
    assert TRACES["n"] == before  # the rebuilt files load


def test_an_argument_without_an_exact_description_is_not_stored(store):
    _xla.store_programs(store)

    class Local(eqx.Module):  # a class of a function's own: its name says nothing elsewhere
        def __call__(self, x):
            return jnp.sum(_rosenbrock(x) ** 2)

        residuals = staticmethod(_rosenbrock)

    with jax.enable_x64(True):
        lm = minimise(Local(), LM, BOUNDS, x0=np.array([0.5, 0.5, 0.0]))
    np.testing.assert_allclose(np.asarray(lm.x), [1.0, 1.0, 0.3], atol=1e-6)
    assert not list(store.glob("*.program"))


def _doubled_on_the_host(x):
    out = jax.ShapeDtypeStruct(x.shape, x.dtype)
    return jax.pure_callback(lambda v: np.asarray(v) * 2.0, out, x)


def test_a_program_that_calls_back_into_python_is_not_stored(store):
    """A callback is a pointer into this process: stored, it would call nothing later."""
    _xla.store_programs(store)
    doubled = _xla.fast_compile(_doubled_on_the_host)
    with jax.enable_x64(True):
        np.testing.assert_array_equal(doubled(jnp.arange(3.0)), [0.0, 2.0, 4.0])
    assert not list(store.glob("*.program"))


# -- what a program traces ------------------------------------------------------------------
# A cold calibration's time is mostly tracing, lowering and compiling its programs; these
# check that a program does not trace the same code twice (benchmarks/RESULTS.md, issue 24).


class _Quartic(eqx.Module):
    """A least-squares problem of a size no other test traces (4 parameters, 5 residuals)."""

    def __call__(self, x):
        return jnp.sum(self.residuals(x) ** 2)

    def residuals(self, x):
        return jnp.concatenate([x - jnp.array([0.5, -0.5, 0.25, 1.0]), x[:1] * x[1:2]])


def _counting(calls: list, name: str, f):
    def counted(*args, **kwargs):
        calls.append(name)
        return f(*args, **kwargs)

    return counted


def test_each_lm_program_traces_its_problem_and_its_solver_once(store, monkeypatch):
    """The polish's batch program traces optimistix's LM once (not once more for its output
    types), and the multi-start LM traces the starts' residuals and Jacobian once (not once
    more for its state's shapes)."""
    from handeye_jax.optim import _lm, _multistart, minimise_many, minimise_starts

    calls: list[str] = []
    monkeypatch.setattr(_lm, "_lm", _counting(calls, "optimistix", _lm._lm))
    evaluate = _counting(calls, "jacobian", _multistart._evaluate)
    monkeypatch.setattr(_multistart, "_evaluate", evaluate)
    _xla.store_programs(None)  # traced here, not loaded from an earlier run's store
    box = Box(-2.0 * np.ones(4), 2.0 * np.ones(4))
    with jax.enable_x64(True):
        fns = jax.tree.map(lambda x: jnp.stack([x, x]), _Quartic())
        boxes = Box(np.stack([box.lower] * 2), np.stack([box.upper] * 2))
        polished = minimise_many(fns, LM, boxes, x0=np.zeros((2, 4)))
        assert calls.count("optimistix") == 1, calls
        starts = minimise_starts(_Quartic(), LM, box, np.array([[0.0] * 4, [1.0, 1.0, 0.0, 0.0]]))
        assert calls.count("jacobian") == 1, calls  # the loop's body; its first pass evaluates
    np.testing.assert_allclose(np.asarray(polished.x)[0], np.asarray(starts.x)[0], atol=1e-6)


def test_the_chain_runs_its_sine_polynomials_once_per_shape(monkeypatch):
    """``sincos_deg`` is jitted: a program that calls it for every rotation of the chain (here
    40 times, differentiated and vmapped as the LM's Jacobians are) traces its polynomials at
    most twice for a shape, for the primal and for its JVP rule's call (never, if an earlier
    test traced that shape); inline, they were traced at every call."""
    from handeye_jax import geometry as geo

    runs: list[str] = []
    monkeypatch.setattr(geo._sincos_deg, "fun", _counting(runs, "body", geo._sincos_deg.fun))

    def chain(a):
        out = 0.0
        for i in range(10):
            R = geo.rot_zyx(a[i], a[i + 1], a[i + 2]) @ geo.rot_z(a[i]) @ geo.rot_x(a[i + 1])
            out = out + (R @ geo.rot_y(a[i + 2])).sum()
        return out

    with jax.enable_x64(True):
        jax.make_jaxpr(jax.vmap(jax.jacfwd(chain)))(jnp.ones((3, 12)))
    assert len(runs) <= 4, runs  # shapes (): rot_x, rot_y, rot_z; (3,): rot_zyx's angles
