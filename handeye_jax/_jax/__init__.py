"""How the package runs JAX: float64 without touching the user's global configuration, XLA's
options per kind of program, and the programs kept between runs (``jax.export``)."""
