"""How the package runs JAX: float64 without touching the user's global configuration, XLA's
options per kind of program, the programs kept between runs (``jax.export``), and a batch of
problems split over the devices (``jax.sharding``)."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_x64": ("float64", "in_float64"),
    "_shard": (
        "Blocks", "padded_size", "per_device", "problem_mesh", "PROBLEMS", "single_device_mesh",
    ),
    "_xla": (
        "fast_compile", "fast_compile_options", "hot_loop", "loop_compiler_options",
        "store_programs", "vectorise_small_loops",
    ),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
