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

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING

__version__ = "0.1.0"

# The names below load on first use (PEP 562), so that ``import handeye_jax.cli`` is quick:
# the command line sets up its Ctrl-C handling before JAX (about a second) is imported.
_SUBMODULES = ("geometry", "models", "optim")
_EXPORTS = {
    "AbstractBlock": "_objective",
    "AbstractObjective": "_objective",
    "LengthBlock": "_objective",
    "LossObjective": "_objective",
    "PriorObjective": "_objective",
    "SquaresBlock": "_objective",
    "Stage1Objective": "_objective",
    "Stage2Objective": "_objective",
    "StageErrors": "_objective",
    "WeightedLengthBlock": "_objective",
    "chain_points": "_objective",
    "errors_of": "_objective",
    "fitness": "_objective",
    "ParameterSpace": "_params",
    "Prior": "_params",
    "put": "_params",
    "resolve_names": "_params",
    "Frames": "_frames",
    "Predictor": "_predictor",
    "float64": "_x64",
    "vectorise_small_loops": "_xla",
    "calibrate": "calibrate",
    "diagnose": "calibrate",
    "recalibrate": "calibrate",
    "Dataset": "_dataset",
    "load_dataset": "_dataset_io",
    "save_dataset": "_dataset_io",
    "InputError": "errors",
    "AbstractModel": "models",
    "AffinePair": "models",
    "DHModel": "models",
    "HTMModel": "models",
    "get_model": "models",
    "Observations": "observations",
    "Rig": "observations",
    "hand_command": "predict",
    "CalibrationResult": "_result",
    "StageResult": "_result",
    "load_result": "_result_io",
    "save_result": "_result_io",
    "Settings": "_settings",
    "update_dataset": "_dataset_io",
    "convert_to_v2": "_dataset_io",
    "Capture": "_dataset",
}


# What a robot PC may lack; Predictor and Frames need none of it.
_JAX_STACK = ("jax", "jaxlib", "equinox", "optimistix", "jaxtyping", "lineax", "jaxlie")


def __getattr__(name: str):
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    try:
        module = importlib.import_module(f"{__name__}.{_EXPORTS[name]}")
    except ImportError as e:
        if (e.name or "").split(".")[0] not in _JAX_STACK:
            raise
        raise ImportError(
            f"handeye_jax.{name} needs JAX, which cannot be imported here ({e}); Predictor "
            "and Frames work without it"
        ) from e
    value = getattr(module, name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_SUBMODULES, *_EXPORTS})


class _Package(types.ModuleType):
    # Importing the submodule ``handeye_jax.calibrate`` makes Python set the package's
    # attribute ``calibrate`` to that module; the package's ``calibrate`` is the function.
    def __setattr__(self, name: str, value) -> None:
        if name == "calibrate" and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

if TYPE_CHECKING:
    from . import geometry, models, optim
    from ._dataset import Capture, Dataset
    from ._dataset_io import convert_to_v2, load_dataset, save_dataset, update_dataset
    from ._frames import Frames
    from ._objective import (
        AbstractBlock,
        AbstractObjective,
        LengthBlock,
        LossObjective,
        PriorObjective,
        SquaresBlock,
        Stage1Objective,
        Stage2Objective,
        StageErrors,
        WeightedLengthBlock,
        chain_points,
        errors_of,
        fitness,
    )
    from ._params import ParameterSpace, Prior, put, resolve_names
    from ._predictor import Predictor
    from ._result import CalibrationResult, StageResult
    from ._result_io import load_result, save_result
    from ._settings import Settings
    from ._x64 import float64
    from ._xla import vectorise_small_loops
    from .calibrate import calibrate, diagnose, recalibrate
    from .errors import InputError
    from .models import AbstractModel, AffinePair, DHModel, HTMModel, get_model
    from .observations import Observations, Rig
    from .predict import hand_command

__all__ = [
    "AbstractBlock",
    "AbstractModel",
    "AbstractObjective",
    "AffinePair",
    "CalibrationResult",
    "Capture",
    "DHModel",
    "Dataset",
    "Frames",
    "HTMModel",
    "InputError",
    "LengthBlock",
    "LossObjective",
    "Observations",
    "ParameterSpace",
    "Predictor",
    "Prior",
    "PriorObjective",
    "Rig",
    "Settings",
    "SquaresBlock",
    "Stage1Objective",
    "Stage2Objective",
    "StageErrors",
    "StageResult",
    "WeightedLengthBlock",
    "calibrate",
    "chain_points",
    "convert_to_v2",
    "diagnose",
    "errors_of",
    "fitness",
    "float64",
    "geometry",
    "get_model",
    "hand_command",
    "load_dataset",
    "load_result",
    "models",
    "optim",
    "put",
    "recalibrate",
    "resolve_names",
    "save_dataset",
    "save_result",
    "update_dataset",
    "vectorise_small_loops",
]
