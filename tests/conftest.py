import os
from pathlib import Path

import jax
import pytest

# In-process CLI calls enable XLA's persistent cache; keep it out of the user's home.
os.environ.setdefault(
    "HANDEYE_JAX_CACHE_DIR", str(Path(__file__).resolve().parents[1] / ".pytest_cache" / "xla")
)


@pytest.fixture(autouse=True)
def _float64():
    """Tests run in float64 the same way users do: scoped, not by flipping global config."""
    with jax.enable_x64(True):
        yield
