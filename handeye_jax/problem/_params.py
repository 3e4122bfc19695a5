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

from ..models import AbstractParametric
from ..optim import Box

#: How a parameter entered a fit.
FREE, FIXED, PRIOR = "free", "fixed", "prior"


@dataclass(frozen=True, eq=False)
class Prior:
    """A Gaussian prior on some parameters, in information form: ``N(mean, precision⁻¹)``.

    The information form holds priors that say nothing about some directions (zero
    precision there), as a previous fit's posterior does when its data did not determine a
    combination of parameters.

    Attributes:
        names: the parameters it covers, in the order of ``mean`` and ``precision``.
        mean: the prior mean, ``(k,)``, in the parameters' units.
        precision: the inverse covariance, ``(k, k)``, symmetric positive semi-definite
            (1/unit², e.g. 1/mm², 1/deg²).
        source: where it came from (a result file, ``"user"``); reported with the fit.
        data_scale_mm: the error scale ``s`` of the data it is combined with (the MAP
            objective weighs the prior by ``s/n``, see :class:`~handeye_jax.PriorObjective`);
            a previous fit of the same rig gives ``F/4``.
        data_sigma_mm: the residual standard deviation (per error component, mm) of the fit
            it came from, whose precision is ``JᵀJ/σ²``: the noise of the new data under the
            same model, for the pulls (``None``: estimated from the new fit's residuals).
        untested: parameters the fit it came from did not determine well enough for its
            Gaussian to be their error (in a weak direction, or at a fold of the tablet's
            sign twin): their pulls are reported but not flagged.
        alternatives: the fits the data it came from could not tell from its optimum (a
            mirror camera mount, the tablet's sign twin), each as its shifts from ``mean`` by
            parameter (their units). A parameter is flagged only when the data pull it away
            from the prior and from the prior moved to each of them.
    """

    names: tuple[str, ...]
    mean: np.ndarray
    precision: np.ndarray
    source: str = "user"
    data_scale_mm: float = 0.25
    data_sigma_mm: float | None = None
    untested: tuple[str, ...] = ()
    alternatives: tuple[Mapping[str, float], ...] = ()

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        mean = np.array(self.mean, dtype=np.float64).reshape(-1)
        P = np.array(self.precision, dtype=np.float64)
        k = len(names)
        if len(set(names)) != k:
            raise ValueError(f"prior names must be distinct (got {names})")
        if mean.shape != (k,) or P.shape != (k, k):
            raise ValueError(
                f"prior mean must have shape ({k},) and precision ({k}, {k}); got {mean.shape} "
                f"and {P.shape}"
            )
        if not (np.isfinite(mean).all() and np.isfinite(P).all()):
            raise ValueError("prior mean and precision must be finite")
        P = 0.5 * (P + P.T)
        if k and np.linalg.eigvalsh(P).min() < -1e-9 * max(float(np.abs(P).max()), 1e-300):
            raise ValueError("prior precision must be positive semi-definite")
        if not (math.isfinite(self.data_scale_mm) and self.data_scale_mm > 0):
            raise ValueError(f"data_scale_mm must be > 0 (got {self.data_scale_mm})")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "precision", P)
        object.__setattr__(self, "data_scale_mm", float(self.data_scale_mm))
        alternatives = tuple({str(n): float(v) for n, v in dict(a).items() if n in names}
                             for a in self.alternatives)  # fmt: skip
        if not all(math.isfinite(v) for a in alternatives for v in a.values()):
            raise ValueError("prior alternatives' shifts must be finite")
        object.__setattr__(self, "alternatives", tuple(a for a in alternatives if a))
        if self.data_sigma_mm is not None:
            if not (math.isfinite(self.data_sigma_mm) and self.data_sigma_mm > 0):
                raise ValueError(f"data_sigma_mm must be > 0 (got {self.data_sigma_mm})")
            object.__setattr__(self, "data_sigma_mm", float(self.data_sigma_mm))

    @classmethod
    def independent(
        cls,
        mean: Mapping[str, float],
        sigma: Mapping[str, float],
        source: str = "user",
        data_scale_mm: float = 0.25,
    ) -> Prior:
        """Independent priors ``mean[name] ± sigma[name]`` (each in the parameter's unit)."""
        names = tuple(mean)
        s = np.array([float(sigma[n]) for n in names])
        if not (np.isfinite(s).all() and (s > 0).all()):
            raise ValueError(f"prior sigmas must be finite and > 0 (got {s.tolist()})")
        m = np.array([float(mean[n]) for n in names])
        return cls(names, m, np.diag(1.0 / s**2), source, data_scale_mm)

    @classmethod
    def from_covariance(
        cls,
        names: Sequence[str],
        mean: Float[np.ndarray, " k"],
        cov: Float[np.ndarray, "k k"],
        source: str = "user",
        data_scale_mm: float = 0.25,
    ) -> Prior:
        """A prior from a full covariance (symmetric positive definite)."""
        cov = np.asarray(cov, dtype=float)
        try:
            np.linalg.cholesky(0.5 * (cov + cov.T))
        except np.linalg.LinAlgError:
            raise ValueError("prior covariance must be positive definite") from None
        return cls(tuple(names), mean, np.linalg.inv(cov), source, data_scale_mm)

    def covariance(self) -> np.ndarray:
        """The covariance (pseudo-inverse of the precision: directions without information
        get 0, see :attr:`sigma` for which)."""
        return np.linalg.pinv(self.precision, hermitian=True)

    @property
    def sigma(self) -> np.ndarray:
        """Each parameter's marginal prior standard deviation, in its unit (``inf`` where the
        prior holds no information on it)."""
        w, V = np.linalg.eigh(self.precision)
        tiny = w <= 1e-12 * max(float(w.max()), 1e-300) if len(w) else w.astype(bool)
        sig = np.sqrt(np.maximum(np.diag(self.covariance()), 0.0))
        unknown = (np.abs(V[:, tiny]) > 1e-6).any(axis=1) if tiny.any() else np.zeros(len(w), bool)
        return np.where(unknown, np.inf, sig)

    def whitener(self) -> np.ndarray:
        """``W`` with ``WᵀW = precision``: ``W·(θ − mean)`` is standard normal under the
        prior (in the directions it informs)."""
        w, V = np.linalg.eigh(self.precision)
        return (V * np.sqrt(np.maximum(w, 0.0))).T

    def neg_log_density(self, values: Float[np.ndarray, " k"]) -> float:
        """``−log N(values; mean, precision⁻¹)``, constant included (full-rank priors)."""
        d = np.asarray(values, dtype=float) - self.mean
        k = len(self.names)
        _, logdet_p = np.linalg.slogdet(self.precision)
        return float(0.5 * d @ self.precision @ d + 0.5 * (k * math.log(2 * math.pi) - logdet_p))

    def marginal(self, names: Iterable[str]) -> Prior:
        """The marginal prior of some of its parameters (the others integrated out: the Schur
        complement of their block of the precision)."""
        keep = [self.names.index(n) for n in names]
        drop = [i for i in range(len(self.names)) if i not in keep]
        P = self.precision
        P_kk = P[np.ix_(keep, keep)]
        if drop:
            P_kd, P_dd = P[np.ix_(keep, drop)], P[np.ix_(drop, drop)]
            P_kk = P_kk - P_kd @ np.linalg.pinv(P_dd, hermitian=True) @ P_kd.T
        return Prior(tuple(self.names[i] for i in keep), self.mean[keep], P_kk, self.source,
                     self.data_scale_mm, self.data_sigma_mm, self._untested(keep),
                     self._alternatives(keep))  # fmt: skip

    def conditional(self, names: Iterable[str], others: Mapping[str, float]) -> Prior:
        """The prior of ``names`` given the other parameters' values ``others``."""
        keep = [self.names.index(n) for n in names]
        drop = [i for i in range(len(self.names)) if i not in keep]
        P = self.precision
        P_kk = P[np.ix_(keep, keep)]
        mean = self.mean[keep]
        if drop:
            d_o = np.array([others[self.names[i]] for i in drop]) - self.mean[drop]
            mean = mean - np.linalg.pinv(P_kk, hermitian=True) @ P[np.ix_(keep, drop)] @ d_o
        return Prior(tuple(self.names[i] for i in keep), mean, P_kk, self.source,
                     self.data_scale_mm, self.data_sigma_mm, self._untested(keep),
                     self._alternatives(keep))  # fmt: skip

    def _untested(self, keep: list[int]) -> tuple[str, ...]:
        return tuple(self.names[i] for i in keep if self.names[i] in self.untested)

    def _alternatives(self, keep: list[int]) -> tuple[dict[str, float], ...]:
        kept = {self.names[i] for i in keep}
        out = ({n: v for n, v in a.items() if n in kept} for a in self.alternatives)
        return tuple(a for a in out if a)

    def alternative_shifts(self) -> list[np.ndarray]:
        """The shifts of :attr:`mean` to each alternative fit, ``(k,)`` each (0 for a
        parameter it does not move)."""
        return [np.array([float(a.get(n, 0.0)) for n in self.names]) for a in self.alternatives]


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
    def box(self) -> Box:
        """The search box of the free parameters."""
        return Box(self.lower, self.upper)

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

    def subspace(self, names: Sequence[str], theta: Float[np.ndarray, " d"]) -> ParameterSpace:
        """The space of the free parameters ``names`` alone, the other free parameters held at
        their values in ``theta`` (the prior becomes its conditional on them)."""
        theta = np.asarray(theta, dtype=float)
        idx = [self.free.index(n) for n in names]
        held = {n: float(theta[i]) for i, n in enumerate(self.free)}
        template = put(self.template, self.free, jnp.asarray(theta))
        prior = None
        if self.prior is not None:
            mine = [n for n in self.prior.names if n in names]
            if mine:
                prior = self.prior.conditional(mine, held)
        fixed = {n: "held at the search's start" for n in self.free if n not in names}
        return ParameterSpace(template, tuple(names), self.lower[idx], self.upper[idx], prior,
                              {**self.fixed_source, **fixed})  # fmt: skip

    def embed(
        self, names: Sequence[str], theta_sub: Float[np.ndarray, " k"], theta: np.ndarray
    ) -> np.ndarray:
        """``theta`` with the free parameters ``names`` set to ``theta_sub``."""
        out = np.array(theta, dtype=float, copy=True)
        out[[self.free.index(n) for n in names]] = np.asarray(theta_sub, dtype=float)
        return out

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
