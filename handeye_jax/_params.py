"""Free, fixed and prior parameters: which of a model's parameters a fit moves, and how.

A fit works on a flat vector ``theta`` of the *free* parameters only. A :class:`ParameterSpace`
puts ``theta`` into a model *template* (a fitted or nominal model) with :func:`equinox.tree_at`;
every other parameter keeps the template's value (it is *fixed*). Some free parameters may
carry a Gaussian :class:`Prior` (mean, covariance in their units), which makes the fit a MAP
estimate: the prior adds a block of residuals to the objective (see
:class:`~handeye_jax.PriorObjective`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .models import AbstractParametric

#: How a parameter entered a fit.
FREE, FIXED, PRIOR = "free", "fixed", "prior"


@dataclass(frozen=True, eq=False)
class Prior:
    """A Gaussian prior on some parameters: ``N(mean, cov)`` in the parameters' own units.

    Attributes:
        names: the parameters it covers, in the order of ``mean`` and ``cov``.
        mean: the prior mean, ``(k,)``.
        cov: the prior covariance, ``(k, k)``, symmetric positive definite (units², e.g. mm²,
            deg², mm·deg off the diagonal).
        source: where it came from (a result file, ``"user"``); reported with the fit.
    """

    names: tuple[str, ...]
    mean: np.ndarray
    cov: np.ndarray
    source: str = "user"

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        mean = np.array(self.mean, dtype=np.float64).reshape(-1)
        cov = np.array(self.cov, dtype=np.float64)
        k = len(names)
        if len(set(names)) != k:
            raise ValueError(f"prior names must be distinct (got {names})")
        if mean.shape != (k,) or cov.shape != (k, k):
            raise ValueError(
                f"prior mean must have shape ({k},) and cov ({k}, {k}); got {mean.shape} and "
                f"{cov.shape}"
            )
        if not (np.isfinite(mean).all() and np.isfinite(cov).all()):
            raise ValueError("prior mean and covariance must be finite")
        cov = 0.5 * (cov + cov.T)
        try:
            np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            raise ValueError("prior covariance must be positive definite") from None
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", cov)

    @classmethod
    def independent(
        cls, mean: Mapping[str, float], sigma: Mapping[str, float], source: str = "user"
    ) -> Prior:
        """Independent priors: ``mean[name] ± sigma[name]`` (each in the parameter's unit)."""
        names = tuple(mean)
        s = np.array([float(sigma[n]) for n in names])
        if not (np.isfinite(s).all() and (s > 0).all()):
            raise ValueError(f"prior sigmas must be finite and > 0 (got {s.tolist()})")
        return cls(names, np.array([float(mean[n]) for n in names]), np.diag(s**2), source)

    @property
    def sigma(self) -> np.ndarray:
        """Each parameter's prior standard deviation, in its unit."""
        return np.sqrt(np.diag(self.cov))

    def whitener(self) -> np.ndarray:
        """``W`` with ``WᵀW = cov⁻¹``: ``W·(θ − mean)`` is standard normal under the prior."""
        L = np.linalg.cholesky(self.cov)
        return np.linalg.inv(L)

    def neg_log_density(self, values: Float[np.ndarray, " k"]) -> float:
        """``−log N(values; mean, cov)``, the full Gaussian, constant included."""
        d = np.asarray(values, dtype=float) - self.mean
        k = len(self.names)
        _, logdet = np.linalg.slogdet(self.cov)
        return float(0.5 * d @ np.linalg.solve(self.cov, d) + 0.5 * (k * math.log(2 * math.pi)
                                                                        + logdet))  # fmt: skip

    def restrict(self, names: Iterable[str]) -> Prior:
        """The marginal prior of some of its parameters (a Gaussian's marginal: the sub-block)."""
        names = tuple(names)
        idx = [self.names.index(n) for n in names]
        return Prior(names, self.mean[idx], self.cov[np.ix_(idx, idx)], self.source)


@dataclass(frozen=True, eq=False)
class ParameterSpace:
    """Which parameters of ``template`` a fit moves, within which box, and under which prior.

    Attributes:
        template: the model (or correction) whose non-free parameters are held at its values.
        free: the names of the free parameters, in ``theta`` order.
        lower, upper: the search box of the free parameters, in their units, ``(d,)``.
        prior: a Gaussian prior on some of the free parameters, or ``None``.
        fixed_source: where the fixed values came from (``"template"``, a result file), by name.
    """

    template: AbstractParametric
    free: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    prior: Prior | None = None
    fixed_source: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self):
        names = type(self.template).param_names
        free = tuple(self.free)
        unknown = [n for n in free if n not in names]
        if unknown:
            raise ValueError(f"unknown parameter {unknown[0]!r}; known: {', '.join(names)}")
        if len(set(free)) != len(free):
            raise ValueError(f"free parameters must be distinct (got {free})")
        lo = np.array(self.lower, dtype=np.float64).reshape(-1)
        hi = np.array(self.upper, dtype=np.float64).reshape(-1)
        if lo.shape != (len(free),) or hi.shape != (len(free),):
            raise ValueError(f"bounds must have one entry per free parameter ({len(free)})")
        if not (lo < hi).all():
            bad = free[int(np.argmin(hi - lo))]
            raise ValueError(f"search range of {bad} must have lo < hi")
        if self.prior is not None:
            outside = [n for n in self.prior.names if n not in free]
            if outside:
                raise ValueError(f"prior on {outside[0]!r}, which is not free")
        object.__setattr__(self, "free", free)
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)
        object.__setattr__(self, "fixed_source", dict(self.fixed_source))

    @classmethod
    def all_free(
        cls,
        template: AbstractParametric,
        search: Mapping[str, tuple[float, float]] | None = None,
    ) -> ParameterSpace:
        """Every parameter free in its search range (the paper's fit)."""
        model_cls = type(template)
        lo, hi = model_cls.search_bounds(search)
        return cls(template, model_cls.param_names, lo, hi)

    @property
    def d(self) -> int:
        return len(self.free)

    @property
    def fixed(self) -> tuple[str, ...]:
        return tuple(n for n in type(self.template).param_names if n not in self.free)

    def status(self) -> dict[str, str]:
        """Each parameter's role in the fit: ``"free"``, ``"prior"`` or ``"fixed"``."""
        with_prior = set(self.prior.names) if self.prior is not None else set()
        return {
            n: (PRIOR if n in with_prior else FREE) if n in self.free else FIXED
            for n in type(self.template).param_names
        }

    def theta(self, model: AbstractParametric | None = None) -> np.ndarray:
        """The free parameters' values in ``model`` (default: the template), ``(d,)``."""
        model = self.template if model is None else model
        return np.array([float(getattr(model, n)) for n in self.free])

    def clip(self, theta: Float[np.ndarray, " d"]) -> np.ndarray:
        """``theta`` moved into the box (a start from a previous result may lie outside)."""
        return np.clip(np.asarray(theta, dtype=float), self.lower, self.upper)

    def prior_indices(self) -> tuple[int, ...]:
        """Positions in ``theta`` of the prior's parameters, in the prior's order."""
        if self.prior is None:
            return ()
        return tuple(self.free.index(n) for n in self.prior.names)


def put(
    template: AbstractParametric, free: Sequence[str], theta: Float[Array, " d"]
) -> AbstractParametric:
    """``template`` with the parameters ``free`` set to ``theta`` (works on tracers)."""
    if not free:
        return template
    return eqx.tree_at(
        lambda m: tuple(getattr(m, n) for n in free),
        template,
        tuple(theta[i] for i in range(len(free))),
    )


def values(model: AbstractParametric, names: Sequence[str]) -> Float[Array, " k"]:
    """The parameters ``names`` of ``model`` as a flat vector."""
    return jnp.stack([jnp.asarray(getattr(model, n)) for n in names])


def resolve_names(cls: type[AbstractParametric], spec: Iterable[str]) -> tuple[str, ...]:
    """Group names (``camera``, ``tablet``, ``pen``…) and parameter names → parameter names.

    Returned in the class's ``param_names`` order; raises :class:`ValueError` naming an unknown
    entry and what is known.
    """
    groups: Mapping[str, tuple[str, ...]] = getattr(cls, "groups", {})
    chosen: set[str] = set()
    for item in spec:
        if item in groups:
            chosen.update(groups[item])
        elif item in cls.param_names:
            chosen.add(item)
        else:
            known = [*groups, *cls.param_names]
            raise ValueError(f"unknown group or parameter {item!r}; known: {', '.join(known)}")
    return tuple(n for n in cls.param_names if n in chosen)
