"""The parts of a result, typed: what each stage's search did, its prior, the sign twin, the
hand heights, the warnings, and the diagnostics (written by ``diagnostics/``, carried here
because the result's file holds them).

Each is a frozen dataclass whose fields name their units; its JSON form, written and read
back checked, is described by its fields (:mod:`handeye_jax._core._schema`), so the result
file's schema is these classes and the top-level table of :mod:`._result_io`. Where a JSON
key is the paper's symbol (``F``, ``f1``) the field says ``_mm`` and maps to it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Literal

from .._core import Reader, count, each, length, spec
from ..problem import JacobianAnalysis

# -- one stage's search ------------------------------------------------------------------


@dataclass(frozen=True)
class Residual:
    """One landmark's (or row's) error vectors and lengths of both terms at a fit, mm."""

    strict: ClassVar[bool] = True

    m: int
    image_vs_tablet_xy_mm: tuple[float, float]
    image_vs_tablet_mm: float = spec(check=length)
    hand_xy_mm: tuple[float, float] = spec()
    hand_mm: float = spec(check=length)


@dataclass(frozen=True)
class DESummary:
    """What DE did in a stage: the parameters it searched and, if it ran, the value at its
    best member (the whole objective's, mm), its generations and evaluations, and whether its
    population converged."""

    searched: tuple[str, ...] | None = spec(omit="none", default=None)
    F_mm: float | None = spec("F", omit="none", default=None)
    generations: int | None = spec(check=count, omit="none", default=None)
    evaluations: int | None = spec(check=count, omit="none", default=None)
    converged: bool | None = spec(omit="none", default=None)


@dataclass(frozen=True)
class RestartSummary:
    """The LM restarts of a stage: how many, how many from the DE population's other optima,
    the lowest value one reached (mm), how many ended within 1e-4 mm of the result, and on how
    many landmarks they searched when fewer than all."""

    starts: int = spec(check=count)
    from_population: int = spec(check=count)
    best_F_mm: float = spec("best_F")
    reached_result: int = spec(check=count)
    landmarks: int | None = spec(check=count, omit="none", default=None)


@dataclass(frozen=True)
class PolishSummary:
    """The LM polish of a stage and which search found its optimum.

    Attributes:
        ran: LM ran (settings.polish).
        accepted: the optimum is lower than DE's best (``F_before_mm``).
        F_before_mm, F_after_mm: the value minimised at DE's best and at the optimum, mm.
        steps, solver_converged: the polish from DE's best: iterations, its own stop rule held.
        restarts: the LM restarts.
        found_by: which search found the optimum.
        replaced_F_mm: the optima a multi-start refit replaced, mm.
        pinned: the parameters LM left on a bound (the first results' field).
    """

    ran: bool | None = spec(omit="none", default=None)
    accepted: bool | None = spec(omit="none", default=None)
    F_before_mm: float | None = spec("F_before", omit="none", default=None)
    steps: int | None = spec(check=count, omit="none", default=None)
    solver_converged: bool | None = spec(omit="none", default=None)
    restarts: RestartSummary | None = spec(omit="none", default=None)
    F_after_mm: float | None = spec("F_after", omit="none", default=None)
    found_by: str | None = spec(omit="none", default=None)
    replaced_F_mm: tuple[float, ...] = spec("replaced_F", omit="empty", default=())
    pinned: tuple[str, ...] | None = spec(omit="none", default=None)


@dataclass(frozen=True)
class Convergence:
    """DE's best value after each generation and the population's median after each chunk of
    generations, mm, with the generations the medians were taken at."""

    best_F_mm: tuple[float, ...] | None = spec("best_F", omit="none", default=None)
    median_F_mm: tuple[float, ...] | None = spec("median_F", omit="none", default=None)
    median_generation: tuple[int, ...] | None = spec(omit="none", default=None)

    def checked(self, r: Reader, where: str) -> Convergence:
        gens = self.median_generation
        if gens is None:
            if self.median_F_mm is None:
                return self
            # The first results recorded the median every generation.
            return Convergence(self.best_F_mm, self.median_F_mm,
                               tuple(range(1, len(self.median_F_mm) + 1)))  # fmt: skip
        for i, g in enumerate(gens):
            if g < 1:
                r.fail(f"{where}.median_generation[{i}]", f"must be at least 1 (got {g})")
        if self.median_F_mm is not None and len(gens) != len(self.median_F_mm):
            r.fail(f"{where}.median_generation", f"must have one generation per median_F "
                   f"({len(self.median_F_mm)}) (got {len(gens)})")  # fmt: skip
        return self


# -- a prior and the sign twin -----------------------------------------------------------


@dataclass(frozen=True)
class Pull:
    """How far the data pulled one prior parameter: its prior mean and σ, the fitted value
    and its posterior σ (each in the parameter's unit; σ ``None``: unbounded or
    undetermined), the ``pull`` (for a tested parameter the new data inform, the
    likelihood-ratio form of Baarda's w-test, from refits with its prior mean free, its sign
    where that refit puts the parameter against the prior mean; for the others the linear
    w-test) and the marginal one, in σ; and
    ``follows``: the flagged parameter whose shift, once accounted for (with those of the
    parameters freed before it), makes this one's pull vanish: it follows it, correlated,
    rather than moving itself."""

    param: str
    mean: float
    sigma: float | None
    value: float
    posterior_sigma: float | None
    pull: float
    marginal_pull: float | None = spec(omit="none", default=None)
    follows: str | None = spec(omit="none", default=None)


@dataclass(frozen=True)
class PriorReport:
    """A stage's prior (its source, the parameters it covers, their mean and precision, the
    data scale and noise σ of the fit it came from, mm) and each parameter's pull; the
    ``untested`` ones (the fit it came from did not determine them) are not flagged, and the
    others only when the data pull them from each of the ``alternatives`` too: the fits the
    data it came from could not exclude, as shifts by parameter (:class:`~handeye_jax.Prior`)."""

    source: str
    names: tuple[str, ...]
    mean: tuple[float, ...]
    precision: tuple[tuple[float, ...], ...]
    data_scale_mm: float
    pulls: tuple[Pull, ...] = ()
    data_sigma_mm: float | None = spec(omit="none", default=None)
    untested: tuple[str, ...] = spec(omit="empty", default=())
    alternatives: tuple[dict[str, float], ...] = spec(omit="empty", default=())


@dataclass(frozen=True)
class SignTwin:
    """The sign twin of a stage-1 fit: the parameters whose joint sign flip mirrors the tablet
    through its plane, their values found, and F (mm) there and at the flip."""

    params: tuple[str, ...]
    found: dict[str, float]
    F_found_mm: float = spec("F_found")
    F_flipped_mm: float = spec("F_flipped")
    note: str = ""


@dataclass(frozen=True)
class RigChange:
    """A value of the rig that differs from the prior's, accepted: the dataset's field
    (``camera.fx``, ``tablet.ppi``, …), its ``previous`` and ``new`` value in ``unit`` (``px``,
    ``deg``, or ``""`` for a pure number)."""

    name: str = spec("field")
    previous: float = spec()
    new: float = spec()
    unit: str = spec()


@dataclass(frozen=True)
class Recalibration:
    """Where a recalibration started: the previous result, what was refitted, how the other
    parameters entered (``"prior"``: its posterior; ``"fixed"``: held), and the rig's changes
    since the prior that the user accepted (``--accept-rig-change``)."""

    previous: str
    refit: tuple[str, ...]
    others: Literal["prior", "fixed"]
    rig_changes: tuple[RigChange, ...] = spec(omit="empty", default=())


@dataclass(frozen=True, eq=False)
class FitWarning:
    """One thing a user should know about a result, as one line of text.

    ``kind`` says what it is about (``"fit"``: F is no rig's; ``"residuals"``: none left
    over; ``"bound"``: a parameter on its search bound; ``"prior"``: the data pull a prior
    parameter; ``"convention"``: another hand-angle convention fits better; ``"file"``: read
    back from a result file, which keeps the text alone), ``param`` the parameter, if one.
    Two warnings are equal when their texts are: a file keeps the text alone.
    """

    text: str
    kind: Literal["fit", "residuals", "bound", "prior", "convention", "file"] = "file"
    param: str | None = None

    def __str__(self) -> str:
        return self.text

    def __eq__(self, other: object) -> bool:
        return isinstance(other, FitWarning) and other.text == self.text

    def __hash__(self) -> int:
        return hash(self.text)

    def to_json(self) -> str:
        return self.text

    @classmethod
    def from_json(cls, r: Reader, x: object, where: str) -> FitWarning:
        if not isinstance(x, str):
            r.fail(where, f"must be a string (got {type(x).__name__})")
        return cls(x)


# -- the diagnostics ---------------------------------------------------------------------


@dataclass(frozen=True)
class Mode:
    """One distinct optimum of a population or of the multi-start refits: its best value
    (mm), how many members it holds, how its best member differs from the fit, whether it is
    the fit's sign twin, and its parameters."""

    F_mm: float = spec("F")
    members: int = spec(check=count)
    differs_from_fit: dict[str, float] | None = spec(omit="none", default=None)
    # Older results compared each optimum with the population's best member.
    differs_from_best: dict[str, float] | None = spec(omit="none", default=None)
    sign_twin: bool = False
    params: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class BoundHit:
    """A parameter on a bound of the range it was searched in (its unit), what would help
    (``advice``) and a wider range to try where one would (``widen_to``; ``None``: widening
    would not help, e.g. along a weak direction or for a prior's parameter), and why it is
    there (``reason``: a prior's parameter pulled far, a weak direction, the closed-form
    estimate outside or inside the range, or no estimate to tell)."""

    param: str
    value: float
    unit: str
    side: Literal["lower", "upper"]
    range: tuple[float, float]
    widen_to: tuple[float, float] | None = None
    advice: str | None = spec(omit="none", default=None)
    reason: Literal["prior", "weak", "estimate outside", "estimate inside", "range"] | None = spec(
        omit="none", default=None)


@dataclass(frozen=True)
class HeldOut:
    """A landmark's (or row's) held-out error lengths, mm: each term's, after a refit
    without it."""

    strict: ClassVar[bool] = True

    m: int
    image_vs_tablet_mm: float = spec(check=length)
    hand_mm: float = spec(check=length)


@dataclass(frozen=True)
class LeaveOneOut:
    """Leave-one-out: each landmark's held-out errors, their means (the held-out f1, f2 and
    F) and the fit's in-sample F, mm."""

    strict: ClassVar[bool] = True

    held_out_mm: tuple[HeldOut, ...]
    f1_mm: float = spec("f1", check=length)
    f2_mm: float = spec("f2", check=length)
    F_mm: float = spec("F", check=length)
    in_sample_F_mm: float = spec("in_sample_F", check=length)


def _positive(r: Reader, x: float, where: str) -> float:
    if not x > 0:
        r.fail(where, f"must be > 0 (got {x})")
    return x


@dataclass(frozen=True)
class StageDiagnostics(JacobianAnalysis):
    """A stage's diagnostics: the Jacobian's analysis at the fit (σ, standard deviations,
    precision, singular values, weak directions), the free parameters, the optima in the final
    DE population, the parameters on a bound, leave-one-out and how it was computed, the
    outlier landmarks and (stage 1) the optima of the multi-start refits."""

    free: tuple[str, ...] = ()
    modes: tuple[Mode, ...] = ()
    bound_hits: tuple[BoundHit, ...] = ()
    loo: LeaveOneOut | None = spec(omit="none", default=None)
    loo_method: str | None = spec(omit="none", default=None)
    outliers: tuple[int, ...] = ()
    local_optima: tuple[Mode, ...] | None = spec(omit="none", default=None)
    #: Each σ's degrees of freedom (:func:`~handeye_jax.problem.std_dof`; ``None``: no
    #: estimated noise scale enters it): its 95 % interval is ± t·σ, Student's t at that many.
    #: Stage 2's count its own noise scales only.
    std_dof: dict[str, float | None] | None = spec(omit="none", default=None,
                                                   check=each(_positive))


@dataclass(frozen=True)
class Convention:
    """A hand-angle convention ``φ = zero + sign·θh``."""

    zero_deg: float
    sign: int


@dataclass(frozen=True)
class ConventionFit(Convention):
    """A convention and the lowest F1st a refit under it reached, mm."""

    F_mm: float = spec("F")


@dataclass(frozen=True)
class ConventionCheck:
    """Stage 1 refitted under each hand-angle convention: the declared one, each one's F1st,
    whether the declared one passed, the warning if it did not, and how it was checked."""

    declared: Convention
    fits: tuple[ConventionFit, ...]
    passed: bool
    warning: str | None
    method: str = ""


@dataclass(frozen=True)
class Scope:
    """Where a calibration holds: its captures (how many, their hand heights and angles, the
    landmarks' depths, the first capture's position), the camera mount's shift/tilt
    trade-offs left, and the expected hand-command error (1σ, mm) from the first capture pose
    moved up or down (keys: the move, ``"+50"``), all in mm and deg."""

    captures: int
    capture_heights_mm: tuple[float, float]
    hand_angles_deg: tuple[float, float]
    depth_mm: tuple[float, float]
    capture_position_mm: tuple[float, float, float]
    camera_tradeoffs: tuple[str, ...]
    expected_error_mm: dict[str, float]


@dataclass(frozen=True)
class Deployment:
    """Which stage to deploy, and the evidence for it.

    Attributes:
        stage: 1 (eq. 8, the model alone) or 2 (eq. 25, with the affine correction).
        evidence: ``"leave-one-out"`` (each touch predicted by both stages refitted without
            it), ``"held-out"`` (touches the fit never saw) or ``"none"``.
        stage1_mm, stage2_mm: the mean held-out hand error of each stage, mm (what a touch
            misses by), or ``None`` without evidence.
        difference_se_mm: the standard error of the mean paired difference, mm.
        touches: how many touches the evidence holds.
        reason: the choice in words.
    """

    stage: Literal[1, 2]
    evidence: Literal["leave-one-out", "held-out", "none"]
    reason: str
    stage1_mm: float | None = spec(omit="none", default=None)
    stage2_mm: float | None = spec(omit="none", default=None)
    difference_se_mm: float | None = spec(omit="none", default=None)
    touches: int | None = spec(check=count, omit="none", default=None)


#: The stage to deploy without evidence: the model alone.
NO_EVIDENCE = Deployment(
    stage=1, evidence="none",
    reason="no leave-one-out evidence (diagnostics skipped): stage 1, the model alone; stage 2 "
    "is deployed only where held-out touches show that it predicts better",
)  # fmt: skip


@dataclass(frozen=True)
class ExpectedError:
    """The touching error the fit's covariance and noise model predict for the stage to
    deploy: the mean and the 95th percentile of the hand command's x-y error over targets
    like the calibration's (``where``), mm; validated on twins (``benchmarks/coverage.py``)."""

    stage: Literal[1, 2]
    mean_mm: float = spec(check=length)
    p95_mm: float = spec(check=length)
    targets: int = spec(check=count)
    where: str = ""


@dataclass(frozen=True)
class ErrorMap:
    """The bootstrap's command spread over the workspace, for the stage to deploy, mm.

    Attributes:
        grid_x_mm, grid_y_mm: the map's axes, tablet frame (on the display), mm.
        spread_mm: the mean spread at each grid point, ``(len(grid_y_mm), len(grid_x_mm))``
            rows by y: the mean distance of a resample's command from the resamples' mean,
            over the resamples and the hand angles, mm.
        landmarks_mm: the landmarks drawn, tablet frame, mm ``(n, 2)``.
        capture_z_mm: the hand's height at the first capture (the map's pictures), mm.
        rises_mm: capture heights above the first capture's, mm.
        height_mean_mm, height_p95_mm: the spread's mean and 95th percentile over the
            landmarks seen from each of those heights, mm.
        height_predicted_mm: the covariance's prediction of the mean there, mm, or ``None``.
    """

    grid_x_mm: tuple[float, ...]
    grid_y_mm: tuple[float, ...]
    spread_mm: tuple[tuple[float, ...], ...]
    landmarks_mm: tuple[tuple[float, float], ...]
    capture_z_mm: float
    rises_mm: tuple[float, ...]
    height_mean_mm: tuple[float, ...]
    height_p95_mm: tuple[float, ...]
    height_predicted_mm: tuple[float, ...] | None = spec(omit="none", default=None)


@dataclass(frozen=True)
class Bootstrap:
    """Repeatability: the result refitted on resamples of its own data (``calibrate
    --bootstrap B``), and how far the hand commands of the stage to deploy move between them.

    Attributes:
        resamples: the resamples drawn (B).
        fitted: how many of them were fitted (the others could not be, e.g. too few distinct
            landmarks left to determine the parameters).
        seed: the seed of the resampling (each refit uses the result's settings and seed).
        stage: the stage whose commands are compared (the result's stage to deploy).
        resampled: what a resample draws, in words.
        spread_mean_mm, spread_p95_mm: the mean and 95th percentile, over the resamples and
            the targets, of the distance of a resample's hand command from the resamples'
            mean command, mm.
        targets: how many targets (views of the landmarks, each at several hand angles).
        predicted_mean_mm, predicted_p95_mm: the same statistics of the command error the
            fit's covariance predicts (the fit's part alone, targets measured exactly), mm;
            ``None`` without a noise model (a loss other than ``ml``).
        touching_mean_mm: the expected touching error for the same targets (the fit's part and
            each target's own measurement), mm; ``None`` likewise.
        seconds: the wall time of the refits and the statistics, s.
        map: the spread over the tablet area and over capture heights, or ``None``.
    """

    resamples: int = spec(check=count)
    fitted: int = spec(check=count)
    seed: int = spec()
    stage: Literal[1, 2] = spec()
    resampled: str = spec()
    spread_mean_mm: float = spec(check=length)
    spread_p95_mm: float = spec(check=length)
    targets: int = spec(check=count)
    predicted_mean_mm: float | None = spec(check=length, omit="none", default=None)
    predicted_p95_mm: float | None = spec(check=length, omit="none", default=None)
    touching_mean_mm: float | None = spec(check=length, omit="none", default=None)
    seconds: float = spec(check=length, default=0.0)
    map: ErrorMap | None = spec(omit="none", default=None)


@dataclass(frozen=True)
class Ambiguity:
    """A fit the data cannot tell from the result's: what it is, how it differs, how far its
    hand commands are from the result's elsewhere, and what would tell them apart.

    Attributes:
        kind: its name (``"tablet sign twin"``, ``"mirror camera mount"``, ``"sum only"``,
            ``"shift-tilt trade-off"``).
        differs: the parameters it changes and by how much (their units).
        delta_F_mm: its F less the result's, mm (the paper's measure).
        delta_chi2: its −2 log-likelihood less the result's under the noise model (at least
            the preset's noise), or ``None``.
        here_mm: the largest change of the hand commands for the calibration's own views, mm.
        elsewhere_mm: the mean and largest change for the same points seen from
            ``elsewhere``, mm.
        elsewhere: where those views are taken from, in words.
        separate_by: what would tell the two apart.
        edge: ``True`` for the far end of a weak direction's valley, as far as the data allow
            (not a second optimum); ``None`` otherwise.
        fold: ``True`` for the sign twin met at its fold (the fit's tablet tilts both 0): the
            tilts' size is not known, so they have no σ; ``None`` otherwise (files written
            before it mark the fold by shifts of exactly 0).
    """

    kind: str
    differs: dict[str, float]
    delta_F_mm: float
    here_mm: float = spec(check=length)
    elsewhere_mm: tuple[float, float] = spec()
    elsewhere: str = ""
    separate_by: str = ""
    delta_chi2: float | None = spec(omit="none", default=None)
    edge: bool | None = spec(omit="none", default=None)
    fold: bool | None = spec(omit="none", default=None)


@dataclass(frozen=True)
class Pose:
    """A frame on the flange as a robot engineer reads it: position (mm), fixed-axis roll,
    pitch and yaw (deg, ``R = Rz(yaw)·Ry(pitch)·Rx(roll)``, URDF's) and the unit quaternion
    ``(x, y, z, w)``, ``w ≥ 0``; each with its standard deviation from the fit's covariance,
    ``None`` where the data do not determine it (then ``note`` says why). A point (the pen
    tip) has no rotation."""

    xyz_mm: tuple[float | None, float | None, float | None]
    xyz_sigma_mm: tuple[float | None, float | None, float | None]
    rpy_deg: tuple[float, float, float] | None = spec(omit="none", default=None)
    rpy_sigma_deg: tuple[float | None, float | None, float | None] | None = spec(
        omit="none", default=None)  # fmt: skip
    quaternion_xyzw: tuple[float, float, float, float] | None = spec(omit="none", default=None)
    quaternion_sigma: tuple[float | None, float | None, float | None, float | None] | None = spec(
        omit="none", default=None)  # fmt: skip
    note: str = ""


@dataclass(frozen=True)
class Mount:
    """``T_tool0_camera`` (the camera's optical frame in the flange, tool0) and the pen tip in
    the flange, with what the data determine of them."""

    camera: Pose
    pen: Pose


@dataclass(frozen=True)
class LossInfo:
    """The loss a fit used and its scale, mm."""

    name: str
    scale_mm: float


@dataclass(frozen=True)
class Diagnostics:
    """What a result can and cannot tell (:func:`handeye_jax.diagnose`): the loss, the
    outlier threshold (mm), each stage's diagnostics, the convention check, the scope, the
    touching error to expect from the stage to deploy, the fits the data cannot tell from
    the result's, the camera and pen on the flange, and the stage-1 parameters whose σ is not
    their error (``weak_params``: in a weak direction, moved half their σ or more by an
    alternative fit, or a whole σ by a weak valley's far end; no σ is given for them); the
    stage-1 parameters a recalibration from this result does not test against its prior
    (``untested_params``: as ``weak_params`` but for the valleys' far ends, which the prior
    check's own benchmark does not need withheld; ``None`` in files written before it, whose
    ``weak_params`` are that set); and the repeatability over resamples of the data
    (``bootstrap``, when asked for: :func:`handeye_jax.bootstrap`)."""

    loss: LossInfo | None = spec(omit="none", default=None)
    outlier_threshold_mm: float | None = spec(omit="none", default=None)
    stage1: StageDiagnostics | None = spec(omit="none", default=None)
    stage2: StageDiagnostics | None = spec(omit="none", default=None)
    convention: ConventionCheck | None = spec(omit="none", default=None)
    scope: Scope | None = None
    expected: ExpectedError | None = spec(omit="none", default=None)
    ambiguities: tuple[Ambiguity, ...] = ()
    mount: Mount | None = spec(omit="none", default=None)
    weak_params: tuple[str, ...] = ()
    untested_params: tuple[str, ...] | None = spec(omit="none", default=None)
    bootstrap: Bootstrap | None = spec(omit="none", default=None)
