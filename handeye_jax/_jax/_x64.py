"""Float64 without touching the user's global JAX configuration.

Importing handeye_jax does not flip ``jax_enable_x64``. Every public entry point that computes
numbers runs inside ``jax.enable_x64(True)``, so results are float64 whatever the caller's
setting. To call the low-level pure functions (models, objectives) in float64 from your own
code, wrap the call in ``with handeye_jax.float64():`` or set ``JAX_ENABLE_X64=1``.
"""

from __future__ import annotations

import functools

import jax


def float64():
    """Context manager: JAX computes in float64 inside it."""
    return jax.enable_x64(True)


def in_float64(fn):
    """Decorator: run ``fn`` with float64 enabled."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with jax.enable_x64(True):
            return fn(*args, **kwargs)

    return wrapper
