"""Properties of the pure geometry and of the models' chains (hypothesis)."""

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from handeye_jax import Rig
from handeye_jax import geometry as geo
from handeye_jax.models import AffinePair, model_registry
from handeye_jax.models._affine import affine_about

angles = st.floats(-360.0, 360.0, allow_nan=False)
FAST = settings(max_examples=40, deadline=None)


@FAST
@given(angles, st.sampled_from([geo.rot_x, geo.rot_y, geo.rot_z]))
def test_rotations_are_proper_orthonormal(a, rot):
    R = np.asarray(rot(a))
    assert R.dtype == np.float64
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    assert abs(np.linalg.det(R) - 1.0) < 1e-13


@FAST
@given(angles, angles, st.sampled_from([geo.rot_x, geo.rot_y, geo.rot_z]))
def test_rotations_about_one_axis_compose_by_adding_angles(a, b, rot):
    np.testing.assert_allclose(rot(a) @ rot(b), rot(a + b), atol=1e-12)


def test_rotation_directions_are_right_handed():
    np.testing.assert_allclose(geo.rot_z(90.0) @ jnp.array([1.0, 0, 0]), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(geo.rot_x(90.0) @ jnp.array([0, 1.0, 0]), [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(geo.rot_y(90.0) @ jnp.array([0, 0, 1.0]), [1, 0, 0], atol=1e-15)


@FAST
@given(
    st.lists(st.tuples(st.floats(0, 640), st.floats(0, 480), st.floats(50, 2000)), min_size=1,
             max_size=8),
    st.floats(300, 1200), st.floats(300, 1200), st.floats(200, 400), st.floats(150, 300),
)  # fmt: skip
def test_backproject_then_project_is_identity(pts, fx, fy, cx, cy):
    pts = np.array(pts)
    p = geo.backproject(jnp.asarray(pts[:, :2]), jnp.asarray(pts[:, 2]), fx, fy, cx, cy)
    uv, z = geo.project(p, fx, fy, cx, cy)
    np.testing.assert_allclose(uv, pts[:, :2], atol=1e-9)
    np.testing.assert_allclose(z, pts[:, 2], rtol=1e-14)


@FAST
@given(st.floats(-50, 50), st.floats(-50, 50), st.lists(angles, min_size=1, max_size=5))
def test_pen_offset_matches_matrix_form_of_eq6(xp, yp, phis):
    t_p = jnp.array([xp, yp, 0.0])
    got = geo.pen_offset(t_p, jnp.asarray(phis))
    want = np.stack([np.asarray(geo.rot_y(-180.0) @ geo.rot_z(phi) @ t_p) for phi in phis])
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_pen_angle_convention():
    assert float(geo.pen_angle_deg(22.5, 90.0, -1.0)) == 67.5
    assert float(geo.pen_angle_deg(22.5, 0.0, 1.0)) == 22.5


def test_px_to_mm_is_eq9():
    assert abs(float(geo.px_to_mm(267.0, 267.0, 2.0)) - 50.8) < 1e-12
    assert abs(geo.mm_per_tablet_px(267, 2) - 25.4 / 267 * 2) < 1e-15


@FAST
@given(st.floats(-180, 180), st.floats(-100, 100), st.floats(-100, 100), st.floats(-100, 100))
def test_htm_matches_transform_points(a, x, y, z):
    R, t = geo.rot_z(a) @ geo.rot_x(a / 2), jnp.array([x, y, z])
    p = jnp.array([[1.0, 2.0, 3.0], [-4.0, 5.0, 0.5]])
    homogeneous = jnp.concatenate([p, jnp.ones((2, 1))], axis=1) @ geo.htm(R, t).T
    np.testing.assert_allclose(homogeneous[:, :3], geo.transform_points(R, t, p), atol=1e-12)


def _random_params(cls, rng):
    lo, hi = cls.search_bounds()
    return cls.from_vector(jnp.asarray(rng.uniform(lo, hi)))


RIG = Rig(617.7, 617.7, 316.5, 242.3, [320.0, -70.0, 290.0], 90.0, -1.0)


@FAST
@given(st.sampled_from(sorted(model_registry())), st.integers(0, 2**31 - 1))
def test_image_to_base_inverts_back_to_the_image(name, seed):
    """image → base → image round trip through any registered model."""
    rng = np.random.default_rng(seed)
    model = _random_params(model_registry()[name], rng)
    uv = rng.uniform([0, 0], [640, 480], size=(6, 2))
    depth = rng.uniform(100, 400, size=6)
    p_base = model.image_to_base(jnp.asarray(uv), jnp.asarray(depth), RIG)
    R_bh, t_bh = RIG.T_base_hand_capture()
    R_hc, t_hc = model.camera_mount()
    p_cam = ((p_base - t_bh) @ R_bh - t_hc) @ R_hc
    uv_back, z_back = geo.project(p_cam, RIG.fx_px, RIG.fy_px, RIG.cx_px, RIG.cy_px)
    np.testing.assert_allclose(uv_back, uv, atol=1e-9)
    np.testing.assert_allclose(z_back, depth, atol=1e-9)


@FAST
@given(st.sampled_from([*sorted(model_registry()), "affine"]), st.integers(0, 2**31 - 1))
def test_vector_and_dict_round_trips(name, seed):
    cls = AffinePair if name == "affine" else model_registry()[name]
    rng = np.random.default_rng(seed)
    theta = rng.uniform(*cls.search_bounds())
    m = cls.from_vector(jnp.asarray(theta))
    np.testing.assert_array_equal(m.to_vector(), theta)
    assert cls.from_dict(m.to_dict()).to_dict() == m.to_dict()
    assert len(cls.param_names) == len(cls.param_units) == len(cls.default_ranges)
    assert set(cls.default_ranges) == set(cls.param_names)


@FAST
@given(st.integers(0, 2**31 - 1))
def test_model_frames_are_rotations(seed):
    rng = np.random.default_rng(seed)
    for cls in model_registry().values():
        m = _random_params(cls, rng)
        for R, _ in (m.camera_mount(), m.tablet_pose()):
            np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-13)
            # Tablet frames may be improper (eq. 16 includes a reflection); |det| is 1.
            assert abs(abs(float(jnp.linalg.det(R))) - 1.0) < 1e-12


@FAST
@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(-10, 10), st.floats(0.8, 1.2),
       st.floats(0.8, 1.2), st.floats(-100, 100), st.floats(-100, 100))  # fmt: skip
def test_affine_matches_eq24_matrix_product(X, Y, th, sx, sy, cx, cy):
    def T(a, b):
        return np.array([[1, 0, a], [0, 1, b], [0, 0, 1.0]])

    c, s = np.cos(np.deg2rad(th)), np.sin(np.deg2rad(th))
    M = (
        T(X, Y)
        @ T(cx, cy)
        @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        @ np.diag([sx, sy, 1.0])
        @ T(-cx, -cy)
    )
    pts = np.array([[1.0, 2.0], [30.0, -40.0], [cx, cy]])
    want = (np.c_[pts, np.ones(3)] @ M.T)[:, :2]
    got = affine_about(jnp.asarray(pts), jnp.array([cx, cy]), *map(jnp.asarray, (X, Y, th, sx, sy)))
    np.testing.assert_allclose(got, want, atol=1e-10)


def test_models_are_pytrees_that_jit_grad_and_vmap():
    cls = model_registry()["htm"]
    lo, hi = cls.search_bounds()
    m = cls.from_vector(jnp.asarray((lo + hi) / 2))
    uv, z = jnp.array([[100.0, 200.0]]), jnp.array([170.0])

    def x_of(model):
        return model.image_to_base(uv, z, RIG)[0, 0]

    g = jax.grad(x_of)(m)
    assert isinstance(g, cls) and np.isfinite(float(g.xc))
    assert float(g.xc) != 0.0  # x of the base point moves with the camera's x offset
    batch = jax.vmap(cls.from_vector)(jnp.stack([m.to_vector()] * 3))
    out = jax.vmap(x_of)(batch)
    np.testing.assert_allclose(out, jax.jit(x_of)(m), atol=1e-12)


@FAST
@given(angles, angles, angles)
def test_closed_form_zyx_equals_the_product(g, b, a):
    want = geo.compose(geo.rot_z(g), geo.rot_y(b), geo.rot_x(a))
    np.testing.assert_allclose(geo.rot_zyx(g, b, a), want, atol=1e-15)
    np.testing.assert_allclose(want, np.asarray(geo.rot_z(g)) @ geo.rot_y(b) @ geo.rot_x(a),
                               atol=1e-15)  # fmt: skip


@FAST
@given(st.floats(-1e4, 1e4, allow_nan=False))
def test_polynomial_sincos_matches_libm(a):
    s, c = geo.sincos_deg(a)
    exact = np.deg2rad(np.longdouble(a))
    assert abs(float(s) - float(np.sin(exact))) < 4e-16
    assert abs(float(c) - float(np.cos(exact))) < 4e-16


def test_sincos_is_exact_at_right_angles():
    s, c = geo.sincos_deg(jnp.arange(-720.0, 721.0, 90.0))
    q = (np.arange(-720, 721, 90) // 90) % 4
    np.testing.assert_array_equal(s, np.array([0.0, 1.0, 0.0, -1.0])[q])
    np.testing.assert_array_equal(c, np.array([1.0, 0.0, -1.0, 0.0])[q])


@FAST
@given(st.floats(-720, 720))
def test_sincos_derivatives_are_exact(a):
    ds = jax.grad(lambda x: geo.sincos_deg(x)[0])(a)
    dc = jax.grad(lambda x: geo.sincos_deg(x)[1])(a)
    k = np.pi / 180
    assert abs(float(ds) - k * np.cos(np.deg2rad(a))) < 1e-16
    assert abs(float(dc) + k * np.sin(np.deg2rad(a))) < 1e-16
    fwd = jax.jacfwd(lambda x: jnp.stack(geo.sincos_deg(x)))(a)
    np.testing.assert_allclose(fwd, [ds, dc], atol=1e-18)
