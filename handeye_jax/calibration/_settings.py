"""How to calibrate: :class:`Settings`, and the one table that checks them in a result file."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from .._core import (
    MAX_GENERATIONS,
    MAX_POPULATION,
    MAX_RESTARTS,
    SEARCH_PRESETS,
    Reader,
    describe,
)

if TYPE_CHECKING:  # JAX: imported on use, so that the command line's --help shows the defaults
    from ..optim import DifferentialEvolution


@dataclass(frozen=True)
class Settings:
    """How to calibrate.

    Attributes:
        model: stage-1 model name, ``"htm"`` or ``"dh"``.
        seed: PRNG seed; the same seed gives the same result bit for bit.
        population: DE population N (both stages).
        generations: most DE generations G (both stages).
        early_stop: stop DE when the population's fitness spread is below ``tol``.
        tol: relative spread for the early stop, ``std(F) <= tol·|mean(F)|``.
        crossover: DE's CR. mutation: DE's F (differential weight).
        polish: run Levenberg–Marquardt from the best DE member of each stage, and from the
            ``restarts``; the lowest F any of them reaches is the stage's result.
        restarts: LM starts in each stage besides the best DE member: the best member of each
            other distinct optimum in the final DE population, the rest points of a Latin
            hypercube of the search box; and in stage 1 the multi-start refits (LM from the
            convention check's uniform starts and from the fit). 0 runs none of them. The DE
            alone can settle in a basin that is not the lowest (6 of 50 ``paper`` twins with
            these DE settings, ``benchmarks/miss_rate.py``).
        loss: ``"ml"`` (the default: maximum likelihood under the noise model ``noise``,
            whose scales are estimated from the data; the search runs on the paper's F),
            ``"l1"`` (the paper's mean error length, which reproduces its tables), ``"huber"``
            or ``"cauchy"`` (:mod:`handeye_jax.problem._losses`); a robust loss limits the
            pull of outlier landmarks. Only ``ml`` reports the uncertainty and the expected
            touching error: they are validated for it (``benchmarks/coverage.py``).
        loss_scale_mm: the robust loss's scale, mm; landmarks with an error above
            ``OUTLIER_FACTOR`` (3) times it are flagged as outliers, whatever the loss.
        search: where stage 1's search ranges come from: ``"estimate"``, a box around a
            closed-form estimate of the rig from the data, as wide as its uncertainty and a
            margin; ``"paper"``, the paper's Tables 5 and 6 (the model's ``default_ranges``);
            ``None``, the dataset's ``[search] preset``, else ``"estimate"``. The dataset's
            ``[search]`` ranges override either by name.
        noise: the noise model ``ml`` starts from (:data:`~handeye_jax.NOISE_MODELS`).

    The paper's settings are ``population=10000, generations=10000, early_stop=False``; the
    defaults reach the same optimum on the paper's data in seconds.
    """

    model: str = "htm"
    seed: int = 1
    population: int = 500
    generations: int = 3000
    early_stop: bool = True
    tol: float = 1e-3
    crossover: float = 0.9
    mutation: float = 0.5
    polish: bool = True
    restarts: int = 32
    loss: str = "ml"
    loss_scale_mm: float = 1.0
    search: str | None = None
    noise: str = "paper"

    def de(self) -> DifferentialEvolution:
        """The DE solver these settings configure."""
        from ..optim import DifferentialEvolution

        return DifferentialEvolution(
            population=self.population, generations=self.generations,
            crossover=self.crossover, mutation=self.mutation, tol=self.tol,
            early_stop=self.early_stop,
        )  # fmt: skip

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> Settings:
        """Settings from a result file's ``settings`` (keys it does not know are ignored:
        older results recorded ``diagnostics``)."""
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in values.items() if k in known})

    def to_dict(self) -> dict[str, Any]:
        """The settings as JSON-ready values."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


#: Seeds the DE takes (64-bit integers).
SEED_RANGE = (-(2**63), 2**63 - 1)


def _integer(low: int, high: int) -> Callable[[Reader, Any, str], int]:
    def check(r: Reader, x: Any, where: str) -> int:
        if isinstance(x, bool) or not isinstance(x, int):
            r.fail(where, f"must be an integer (got {describe(x)})")
        if not low <= x <= high:
            got = x if len(str(x)) <= 24 else f"an integer of {len(str(abs(x)))} digits"
            r.fail(where, f"must be {low} to {high} (got {got})")
        return x

    return check


def _boolean(r: Reader, x: Any, where: str) -> bool:
    if not isinstance(x, bool):
        r.fail(where, f"must be true or false (got {describe(x)})")
    return x


def _number(positive: bool = False) -> Callable[[Reader, Any, str], float]:
    return lambda r, x, where: r.number(x, where, positive=positive)


def _choice(known: Callable[[], Any], what: str) -> Callable[[Reader, Any, str], str]:
    def check(r: Reader, x: Any, where: str) -> str:
        names = sorted(known())
        if not isinstance(x, str) or x not in names:
            r.fail(where, f"unknown {what} {describe(x)}; known: {', '.join(names)}")
        return x

    return check


def _models():
    from ..models import model_registry

    return model_registry()


def _losses():
    from ..problem import LOSS_NAMES

    return LOSS_NAMES


def _noises():
    from ..problem import NOISE_MODELS

    return NOISE_MODELS


#: Each setting's check in a result file: the schema of ``settings``, one entry per field.
SETTINGS_SCHEMA: dict[str, Callable[[Reader, Any, str], Any]] = {
    "model": _choice(_models, "model"),
    "seed": _integer(*SEED_RANGE),
    "population": _integer(4, MAX_POPULATION),
    "generations": _integer(1, MAX_GENERATIONS),
    "early_stop": _boolean,
    "tol": _number(),
    "crossover": _number(),
    "mutation": _number(),
    "polish": _boolean,
    "restarts": _integer(0, MAX_RESTARTS),
    "loss": _choice(_losses, "loss"),
    "loss_scale_mm": _number(positive=True),
    "search": lambda r, x, where: x if x is None else _choice(lambda: SEARCH_PRESETS,
                                                              "search preset")(r, x, where),
    "noise": _choice(_noises, "noise model"),
}
#: Settings older results recorded and the fit no longer has (checked, then ignored).
LEGACY_SETTINGS = {"diagnostics": _boolean}


def read_settings(r: Reader, doc: Any, where: str = "settings") -> Settings:
    """Settings from a result file's ``settings`` table, each checked; missing ones default."""
    if not isinstance(doc, dict):
        r.fail(where, f"must be an object (got {describe(doc)})")
    for key, check in {**SETTINGS_SCHEMA, **LEGACY_SETTINGS}.items():
        if key in doc:
            check(r, doc[key], f"{where}.{key}")
    return Settings.from_dict(doc)
