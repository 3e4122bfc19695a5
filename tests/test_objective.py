"""The objectives: vmap consistency, the least-squares form, pluggability of models."""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jaxtyping import Array, Float

from handeye_jax import (
    LossObjective,
    Rig,
    Settings,
    Stage1Objective,
    Stage2Objective,
    calibrate,
    chain_points,
    get_loss,
    snake_grid_px,
    synthesize_dataset,
)
from handeye_jax import geometry as geo
from handeye_jax.models import AbstractModel, AffinePair, model_registry
from handeye_jax.problem import spread_landmarks

RIG = Rig(617.7, 617.7, 316.5, 242.3, [320.0, -70.0, 290.0], 90.0, -1.0)


def _paper_like_obs():
    from handeye_jax import load_dataset
    from tests.common import PAPER

    return load_dataset(PAPER).observations()


#: The population at once, and one member at a time: each compiled once per objective's
#: structure (a jit of a new vmap in every example compiled one program per example).
_batched = eqx.filter_jit(lambda obj, p: jax.vmap(obj)(p))
_single = eqx.filter_jit(lambda obj, x: obj(x))


@pytest.mark.slow
@settings(max_examples=15, deadline=None)
@given(st.sampled_from(sorted(model_registry())), st.integers(0, 2**31 - 1))
def test_vmapped_objective_equals_each_member(name, seed):
    cls = model_registry()[name]
    obs = _paper_like_obs()
    rng = np.random.default_rng(seed)
    pop = jnp.asarray(rng.uniform(*cls.search_bounds(), size=(17, len(cls.param_names))))
    for obj, p in [
        (Stage1Objective(cls, obs), pop),
        (
            Stage2Objective(AffinePair, chain_points(cls.from_vector(pop[0]), obs), 4),
            jnp.asarray(rng.uniform(*AffinePair.search_bounds(), size=(17, 10))),
        ),
    ]:
        batched = np.asarray(_batched(obj, p))
        single = np.array([float(_single(obj, x)) for x in p])
        np.testing.assert_allclose(batched, single, rtol=1e-12)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_squared_residuals_sum_to_f(seed):
    """The LM form minimises the same F as DE (up to the 1e-9 mm smoothing)."""
    obj = Stage1Objective(model_registry()["htm"], _paper_like_obs())
    x = jnp.asarray(np.random.default_rng(seed).uniform(*type(obj.template).search_bounds()))
    assert abs(float(jnp.sum(obj.residuals(x) ** 2)) - float(obj(x))) < 1e-8


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(4, 9))
def test_an_objective_on_some_landmarks_is_the_objective_of_those_landmarks(seed, k):
    """What the restarts search on many landmarks: the same objective, fewer landmarks."""
    from handeye_jax import load_dataset
    from tests.common import PAPER

    rng = np.random.default_rng(seed)
    ds = load_dataset(PAPER)
    centre = ds.observations().centre_index
    idx = spread_landmarks(9, k, include=centre)
    assert centre in idx and np.all(np.diff(idx) > 0) and len(idx) in (k, k + 1)
    fields = ("tablet_px", "image_px", "depth_mm", "hand_xy_mm", "hand_angle_deg",
              "touch_error_px")  # fmt: skip
    few = ds.replace(**{f: getattr(ds, f)[idx] for f in fields})
    x1 = jnp.asarray(rng.uniform(*model_registry()["htm"].search_bounds()))
    x2 = jnp.asarray(rng.uniform(*AffinePair.search_bounds()))
    with jax.enable_x64(True):
        obs, obs_few = ds.observations(), few.observations()
        htm = model_registry()["htm"]
        one, one_few = Stage1Objective(htm, obs), Stage1Objective(htm, obs_few)
        assert float(one.on_landmarks(idx)(x1)) == pytest.approx(float(one_few(x1)), rel=1e-12)
        points = chain_points(htm.from_vector(x1), obs)
        two = Stage2Objective(AffinePair, points, obs.centre_index)
        # the centre of rotation is the same landmark, at its new place in the subset
        two_few = Stage2Objective(AffinePair, chain_points(htm.from_vector(x1), obs_few),
                                  int(np.flatnonzero(idx == centre)[0]))  # fmt: skip
        assert float(two.on_landmarks(idx)(x2)) == pytest.approx(float(two_few(x2)), rel=1e-12)
        robust = LossObjective(one, get_loss("cauchy", 0.5), jnp.ones(9))
        robust_few = LossObjective(one_few, get_loss("cauchy", 0.5), jnp.ones(len(idx)))
        assert float(robust.on_landmarks(idx)(x1)) == pytest.approx(float(robust_few(x1)))
    assert list(spread_landmarks(5, 9)) == [0, 1, 2, 3, 4]
    with pytest.raises(ValueError, match="centre"):
        two.on_landmarks(np.array([i for i in range(9) if i != obs.centre_index]))


class YawOnlyModel(AbstractModel):
    """A third model, defined in one place: camera and tablet turn about z only."""

    xc: Float[Array, ""]
    yc: Float[Array, ""]
    gamma_c: Float[Array, ""]
    xt: Float[Array, ""]
    yt: Float[Array, ""]
    gamma_t: Float[Array, ""]
    xp: Float[Array, ""]
    yp: Float[Array, ""]

    name: ClassVar[str] = "yaw-only-test"
    sign_twin: ClassVar[tuple[str, ...]] = ()
    param_names: ClassVar[tuple[str, ...]] = ("xc", "yc", "gamma_c", "xt", "yt", "gamma_t",
                                              "xp", "yp")  # fmt: skip
    param_units: ClassVar[tuple[str, ...]] = ("mm", "mm", "deg", "mm", "mm", "deg", "mm", "mm")
    groups: ClassVar[dict[str, tuple[str, ...]]] = {
        "camera": ("xc", "yc", "gamma_c"), "tablet": ("xt", "yt", "gamma_t"), "pen": ("xp", "yp"),
    }  # fmt: skip
    default_ranges: ClassVar[dict[str, tuple[float, float]]] = {
        "xc": (-20.0, 20.0), "yc": (20.0, 50.0), "gamma_c": (-30.0, 30.0),
        "xt": (100.0, 200.0), "yt": (0.0, 100.0), "gamma_t": (-30.0, 30.0),
        "xp": (-20.0, 20.0), "yp": (-40.0, -10.0),
    }  # fmt: skip

    def camera_mount(self):
        R = geo.rot_z(self.gamma_c) @ geo.rot_y(180.0) @ geo.rot_x(180.0)
        return R, jnp.stack([self.xc, self.yc, jnp.zeros_like(self.xc)])

    def tablet_pose(self):
        R = geo.rot_z(self.gamma_t) @ geo.rot_x(180.0)
        return R, jnp.stack([self.xt, self.yt, jnp.zeros_like(self.xt)])

    def t_hand_pen(self):
        return jnp.stack([self.xp, self.yp, jnp.zeros_like(self.xp)])


def test_a_third_model_needs_only_its_own_class():
    assert model_registry()["yaw-only-test"] is YawOnlyModel
    truth = YawOnlyModel.from_dict(
        dict(xc=1.0, yc=30.0, gamma_c=3.0, xt=150.0, yt=40.0, gamma_t=-2.0, xp=2.0, yp=-20.0)
    )
    ds = synthesize_dataset(truth, RIG, snake_grid_px(), 22.5 * np.arange(9))
    r = calibrate(ds, Settings(model="yaw-only-test", seed=0, population=200))
    assert r.stage1.F < 1e-6
    assert abs(r.stage1.params["gamma_c"] - 3.0) < 1e-5
