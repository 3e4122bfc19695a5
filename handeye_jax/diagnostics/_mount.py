"""The camera and the pen on the flange, as a robot engineer reads them: ``T_tool0_camera`` as
xyz (mm), roll-pitch-yaw (deg) and a quaternion, and the pen tip, each with the standard
deviation the fit's covariance gives it, or why the data do not determine it.

A component's σ is given only where it does not lean on a direction the data leave weak or
undetermined, nor on an alternative fit the data cannot exclude and that moves hand commands
(:mod:`._ambiguity`): there the linearised σ is not the error (the coverage benchmark counts
only the others), and the number is given without one, with the reason.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from .._jax import fast_compile
from ..calibration import Ambiguity, Mount, Pose, StageDiagnostics
from ..models import AbstractModel
from ..problem import put

#: A component leans on a weak parameter when that parameter's share of its variance is
#: above this.
WEAK_SHARE = 0.1
#: An alternative fit moves commands when they differ by more than this elsewhere, mm.
MOVES_COMMANDS_MM = 0.1
#: An alternative fit the data cannot exclude leaves a parameter's ±t·σ interval honest when
#: it moves it by less than this many σ: were the truth at the alternative, the interval about
#: the fit would still cover it 92 % of the time (95 % at the fit), 93.6 % on average.
AMBIGUOUS_SHIFT_SIGMA = 0.5
#: The far end of a weak direction's valley (:attr:`Ambiguity.edge`) is the edge of what the
#: data allow, not a second optimum: it takes the σ of a parameter it moves by this many σ or
#: more. Set by the one-capture coverage twins, where a parameter riding the valley farther
#: than this is the one whose interval misses (benchmarks/RESULTS.md: 0.5 withholds two
#: thirds of the σ, 1.5 and above let the misses back in).
EDGE_SHIFT_SIGMA = 1.0


@fast_compile
def _pose_and_jacobian(model: AbstractModel, free: tuple[str, ...], x):
    """The camera's (xyz mm, rpy deg, quaternion xyzw) and the pen's xy, and their Jacobians
    in the free parameters ``x``."""

    def f(x):
        m = put(model, free, x)
        R, t = m.camera_mount()
        so3 = jaxlie.SO3.from_matrix(R)
        rpy = so3.as_rpy_radians()
        w, qx, qy, qz = so3.wxyz
        q = jnp.stack([qx, qy, qz, w]) * jnp.where(w >= 0, 1.0, -1.0)
        out = jnp.concatenate([t, jnp.rad2deg(jnp.stack([rpy.roll, rpy.pitch, rpy.yaw])), q,
                               m.t_hand_pen()])  # fmt: skip
        return out, out

    J, value = jax.jacfwd(f, has_aux=True)(x)
    return value, J


def weak_parameters(diag: StageDiagnostics, ambiguities: Sequence[Ambiguity]) -> set[str]:
    """The parameters whose σ is not their error: in a weak or undetermined direction, or
    moved by at least :data:`AMBIGUOUS_SHIFT_SIGMA` of their σ by an alternative fit the data
    cannot exclude (the tablet's sign twin, a mirror camera mount), where the linearised σ
    describes one of several fits, or by :data:`EDGE_SHIFT_SIGMA` by the far end of a weak
    direction's valley; and the tilts of a fit at the sign twin's fold (``Ambiguity.fold``),
    where their size is not known."""
    weak = {p for w in diag.weak_directions for p in w.params}
    for a in ambiguities:
        limit = EDGE_SHIFT_SIGMA if a.edge else AMBIGUOUS_SHIFT_SIGMA
        for p, shift in a.differs.items():
            sd = diag.std.get(p)
            if sd is None or a.fold or not abs(shift) < limit * sd:
                weak.add(p)
    return weak


def mount_report(
    model: AbstractModel,
    free: tuple[str, ...],
    cov: np.ndarray | None,
    weak: set[str],
    why: str,
) -> Mount:
    """The camera and pen on the flange (see the module).

    Args:
        model: the fitted stage-1 model.
        free: its free parameters, the order of ``cov``.
        cov: their covariance (``None``: no σ is given, e.g. for a loss it is not validated
            for).
        weak: the parameters whose σ is not the error (:func:`weak_parameters`).
        why: the reason given for a component leaning on them.
    """
    x = jnp.asarray([float(getattr(model, n)) for n in free])
    value, J = (np.asarray(a) for a in _pose_and_jacobian(model, tuple(free), x))
    sigma: list[float | None] = [None] * len(value)
    notes = []
    if cov is not None:
        share = J**2 * np.diag(cov)[None, :]
        var = np.einsum("ci,ij,cj->c", J, cov, J)
        w_idx = [i for i, n in enumerate(free) if n in weak]
        leans = share[:, w_idx].sum(axis=1) > WEAK_SHARE * np.maximum(share.sum(axis=1), 1e-300)
        sigma = [None if leans[c] else float(np.sqrt(max(var[c], 0.0)))
                 for c in range(len(value))]  # fmt: skip
        if leans.any():
            notes.append(why)
    undetermined = "z: never enters the fit (the hand points down; x-y compared only)"
    camera = Pose(
        xyz_mm=(float(value[0]), float(value[1]), None),
        xyz_sigma_mm=(sigma[0], sigma[1], None),
        rpy_deg=tuple(float(v) for v in value[3:6]),
        rpy_sigma_deg=tuple(sigma[3:6]),
        quaternion_xyzw=tuple(float(v) for v in value[6:10]),
        quaternion_sigma=tuple(sigma[6:10]),
        note="; ".join([*notes, undetermined]) if any(s is None for s in sigma[:10]) and notes
        else undetermined,
    )  # fmt: skip
    pen_notes = [why] if any(s is None for s in sigma[10:12]) and cov is not None else []
    pen = Pose(xyz_mm=(float(value[10]), float(value[11]), None),
               xyz_sigma_mm=(sigma[10], sigma[11], None),
               note="; ".join([*pen_notes, undetermined]))  # fmt: skip
    return Mount(camera=camera, pen=pen)
