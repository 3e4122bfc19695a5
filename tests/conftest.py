import jax
import pytest


@pytest.fixture(autouse=True)
def _float64():
    """Tests run in float64 the same way users do: scoped, not by flipping global config."""
    with jax.enable_x64(True):
        yield
