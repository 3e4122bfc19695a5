"""handeye-jax: differentiable hand-eye calibration for handmade end-effectors, in JAX.

Data flows one way: :mod:`~handeye_jax.dataset` (file → validated arrays) →
:mod:`~handeye_jax.models` + :mod:`~handeye_jax.objective` → :mod:`~handeye_jax.optim` →
:mod:`~handeye_jax.calibrate` (the two stages) → :mod:`~handeye_jax.result` →
:mod:`~handeye_jax.predict` / :mod:`~handeye_jax.summary`.

Float64: importing this package does not change JAX's global configuration. The public entry
points (``calibrate``, ``CalibrationResult.predict``, ``load_dataset``…) compute in float64
whatever your setting; wrap your own calls of the low-level functions in
``with handeye_jax.float64():`` (or set ``JAX_ENABLE_X64=1``) to get float64 there too.
"""

from . import geometry, models, objective, optim
from ._x64 import float64
from ._xla import vectorise_small_loops
from .calibrate import Settings, calibrate
from .dataset import Dataset, load_dataset, save_dataset
from .errors import InputError
from .models import AbstractModel, AffinePair, DHModel, HTMModel, get_model
from .observations import Observations, Rig
from .predict import hand_command
from .result import CalibrationResult, load_result

__version__ = "0.1.0"

__all__ = [
    "AbstractModel",
    "AffinePair",
    "CalibrationResult",
    "DHModel",
    "Dataset",
    "HTMModel",
    "InputError",
    "Observations",
    "Rig",
    "Settings",
    "calibrate",
    "float64",
    "geometry",
    "get_model",
    "hand_command",
    "load_dataset",
    "load_result",
    "models",
    "objective",
    "optim",
    "save_dataset",
    "vectorise_small_loops",
]
