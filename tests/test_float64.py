"""Importing the package leaves JAX's global config alone; the API still computes in float64."""

import os
import subprocess
import sys
import textwrap

import pytest


@pytest.mark.slow
def test_import_does_not_flip_x64_and_api_is_float64_anyway():
    code = textwrap.dedent(
        """
        import os
        import jax, jax.numpy as jnp, numpy as np
        import handeye_jax as hj
        from handeye_jax import snake_grid_px, synthesize_dataset
        assert not jax.config.jax_enable_x64, "import flipped jax_enable_x64"
        assert jnp.ones(1).dtype == jnp.float32
        # the suite's stored programs (tests/conftest.py): what this checks is not compiling
        hj.store_programs(os.path.join(os.environ["HANDEYE_JAX_CACHE_DIR"], "programs"))
        assert not jax.config.jax_enable_x64, "store_programs flipped jax_enable_x64"
        with hj.float64():
            truth = hj.HTMModel.from_dict(dict(xc=-3.0, yc=35.0, alpha_c=-1.5, beta_c=2.0,
                gamma_c=4.0, xt=150.0, yt=40.0, alpha_t=2.0, beta_t=-8.0, gamma_t=-3.0,
                xp=4.0, yp=-25.0))
            rig = hj.Rig(617.7, 617.7, 316.5, 242.3, [320.0, -70.0, 290.0], 90.0, -1.0)
        ds = synthesize_dataset(truth, rig, snake_grid_px(), 22.5 * np.arange(9))
        r = hj.calibrate(ds, hj.Settings(population=200, generations=400))
        assert r.stage1.F < 1e-6, r.stage1.F   # unreachable in float32
        out = r.predict(ds.image_px, ds.depth_mm, ds.hand_angle_deg)
        assert out.dtype == np.float64
        assert not jax.config.jax_enable_x64, "calibrate left x64 on"
        print("ok")
        """
    )
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=os.environ["HANDEYE_JAX_CACHE_DIR"],
               JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
               JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")  # the suite's XLA cache  # fmt: skip
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.strip().endswith("ok")
