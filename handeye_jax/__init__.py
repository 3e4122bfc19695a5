"""handeye-jax: differentiable hand-eye calibration for handmade end-effectors, in JAX.

Data flows one way: :mod:`~handeye_jax.dataset` (file → validated arrays) →
:mod:`~handeye_jax.models` + :mod:`~handeye_jax.objective` → :mod:`~handeye_jax.optim` →
:mod:`~handeye_jax.calibrate` (the two stages) → :mod:`~handeye_jax.result` →
:mod:`~handeye_jax.predict` / :mod:`~handeye_jax.summary`.

Float64: importing this package does not change JAX's global configuration. The public entry
points (``calibrate``, ``CalibrationResult.predict``, ``load_dataset``…) compute in float64
whatever your setting; wrap your own calls of the low-level functions in
``with handeye_jax.float64():`` (or set ``JAX_ENABLE_X64=1``) to get float64 there too.

On a robot PC without JAX, ``Predictor`` and ``Frames`` (NumPy only) still import and
compute hand commands from a result file; everything else needs JAX.
"""

from ._frames import Frames
from ._predictor import Predictor
from .errors import InputError

try:
    import jax as _jax  # noqa: F401
except ImportError as _error:  # a robot PC without JAX: Predictor and Frames still work
    _JAX_ERROR = f"{type(_error).__name__}: {_error}"

    def __getattr__(name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        raise ImportError(f"handeye_jax.{name} needs JAX, which cannot be imported here "
                          f"({_JAX_ERROR}); Predictor and Frames work without it")  # fmt: skip
else:
    from . import geometry, models, objective, optim
    from ._x64 import float64
    from ._xla import vectorise_small_loops
    from .calibrate import Settings, calibrate
    from .dataset import Dataset, load_dataset, save_dataset
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
    "Frames",
    "HTMModel",
    "InputError",
    "Observations",
    "Predictor",
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
