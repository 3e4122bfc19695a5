"""General-purpose optimisers: they minimise functions of flat vectors and know nothing else."""

from .batched import levenberg_marquardt_starts
from .de import DEResult, differential_evolution
from .polish import PolishResult, levenberg_marquardt

__all__ = [
    "DEResult",
    "PolishResult",
    "differential_evolution",
    "levenberg_marquardt",
    "levenberg_marquardt_starts",
]
