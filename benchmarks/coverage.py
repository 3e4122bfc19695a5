"""Issue 26's acceptance: does the uncertainty a calibration reports cover the truth, and is
the touching error it predicts the one measured? And does the stage it deploys do as well as
the better of the two?

    python benchmarks/coverage.py [--seeds N] [--first S] [--configs htm1 htm3 dh1 dh3]
                                  [--rows PATH] [--results PATH] [--quick]

For each configuration (HTM or DH; one capture or three) and seed S = first … first+N−1:
``simulate`` a ``paper``-noise twin (rendered pictures, landmarks detected: one-pixel dots for
one capture, two-pixel dots for three, which reach 90 mm higher), ``calibrate`` it with the
default settings (seed S: maximum likelihood under the ``paper`` noise model, its scales
estimated; a configuration's twins together, in one ``calibrate_batch``, which gives each
twin its own ``calibrate``'s result bit for bit) and ``diagnose`` it. Then:

* **coverage**: for every stage-1 parameter the summary gives a σ for (not in a weak or
  undetermined direction, not moved by an alternative fit the data cannot exclude), whether
  the reported 95 % interval (± t·σ, t the 97.5 % quantile of Student's t with that σ's
  degrees of freedom, ``std_dof``: those of the noise scales it rests on) holds the truth;
  and for each combination the data determine where its parts do not (the DH model's
  θc1 + γc, θt1 + γt). DH twins: the rig's camera sits on the hand's x axis and the tablet's
  corner on the base's x axis (``yc = yt = 0``, ``xc`` drawn in 28–42 mm), so the DH chain
  holds it exactly; its truth is the HTM truth's rotations written in DH form (checked:
  F < 1e-9 mm on the exact data).
* **predicted against measured touching error**: the stage deployed, on the twin's held-out
  targets (one capture: 20 on the display seen from the capture; three captures: 20 in each
  of four groups, seen from the first capture or a new pose 60 mm higher, on the display or
  50 mm above it): the mean and the 95th percentile predicted from the fit's covariance and
  noise model for exactly those targets, against the measured (command against the true
  command); over all twins of a configuration. Also the summary's own number (the verdict,
  for its workspace: the calibration's views touched at 0–180 deg) against the measured held
  out from the first capture on the display.
* **the stage deployed**: its measured mean held-out error against the better stage's.

Rows are written to ``--rows`` (JSON, one per twin, reproducible by seed) and the tables to
``benchmarks/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from scipy.stats import t as student_t

from handeye_jax import (
    PRESETS,
    DHModel,
    Heldout,
    HTMModel,
    Settings,
    calibrate_batch,
    diagnose,
    draw_truth,
    evaluate,
    evaluate_points,
    float64,
    simulate,
    synthesize_dataset,
    vectorise_small_loops,
)
from handeye_jax.calibration import fitted_stages, noise_part, prior_information
from handeye_jax.problem import (
    Stage1Objective,
    StagePoint,
    Targets,
    command_error,
    error_statistics,
    fitness,
    std_dof,
)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from twin_study import write_section  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
ROWS = Path(__file__).resolve().parent / "results" / "coverage.json"
HEADING = "## Uncertainty that covers the truth (issue 26)"
CONFIGS = {"htm1": ("htm", 1), "htm3": ("htm", 3), "dh1": ("dh", 1), "dh3": ("dh", 3)}
#: DH twins' camera offset along the hand's x, mm (drawn per seed; DH holds no y offset).
DH_XC_MM = (28.0, 42.0)


# -- the DH truth of a DH-representable twin ---------------------------------------------------


def _zyx(R: np.ndarray) -> tuple[float, float, float]:
    """``(ψ, θ, φ)``, deg, with ``R = Rz(ψ)·Ry(θ)·Rx(φ)``."""
    theta = -math.degrees(math.asin(max(-1.0, min(1.0, R[2, 0]))))
    phi = math.degrees(math.atan2(R[2, 1], R[2, 2]))
    psi = math.degrees(math.atan2(R[1, 0], R[0, 0]))
    return psi, theta, phi


def _wrap(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def dh_truth(truth) -> dict[str, float]:
    """The DH parameters of a twin with ``yc = yt = 0`` (see the module): the HTM truth's
    rotations in DH form; θc1 and γc split their sum evenly, θt1 = 15 deg."""
    with float64():
        m = truth.htm()
        R_hc = np.asarray(m.camera_mount()[0])
        R_bt = np.asarray(m.tablet_pose()[0])
    psi, beta, alpha = _zyx(R_hc)  # R = Rz(180 + θc1 + γc)·Ry(βc)·Rx(αc)
    s = _wrap(psi - 180.0)
    tpsi, tbeta, talpha = _zyx(R_bt)  # R = Rz(−θt1 − γt)·Ry(−βt)·Rx(180 + αt)
    theta_t1 = 15.0
    return dict(theta_c1=s / 2, a_c1=truth.model["xc"], alpha_c=alpha, beta_c=beta,
                gamma_c=s / 2, theta_t1=theta_t1, a_t1=truth.model["xt"],
                alpha_t=_wrap(talpha - 180.0), beta_t=-tbeta, gamma_t=_wrap(-tpsi - theta_t1),
                xp=truth.model["xp"], yp=truth.model["yp"])  # fmt: skip


def draw(seed: int, model: str, captures: int):
    dot = 1.0 if captures == 1 else 2.0
    if model == "htm":
        return draw_truth(seed, dot_px=dot), None
    xc = float(np.random.default_rng([seed, 26]).uniform(*DH_XC_MM))
    truth = draw_truth(seed, dot_px=dot, fixed={"xc": xc, "yc": 0.0, "yt": 0.0})
    dh = dh_truth(truth)
    with float64():  # the DH chain holds the twin exactly
        exact = synthesize_dataset(truth.htm(), truth.rig(), truth.landmarks_tablet_px,
                                   truth.landmarks_hand_angle_deg, scene=truth.scene())
        obj = Stage1Objective(DHModel, exact.observations())
        F = float(obj(DHModel.from_dict(dh).to_vector()))
    if not F < 1e-9:
        raise AssertionError(f"seed {seed}: the DH truth gives F = {F:.3g} mm, not ~0")
    return truth, dh


# -- one twin ------------------------------------------------------------------------------------


def _heldout(twin) -> Heldout:
    return Heldout(twin.heldout_image_px, twin.heldout_depth_mm, twin.heldout_hand_angle_deg,
                   twin.heldout_tablet_px, twin.heldout_capture_position_mm,
                   twin.heldout_capture_angle_deg, twin.heldout_true_mm,
                   twin.heldout_above_mm)  # fmt: skip


def _targets(result, twin) -> Targets:
    """The held-out targets as the predictor takes them (each with its capture pose)."""
    k = len(twin.heldout_depth_mm)
    if twin.heldout_capture_position_mm is None:
        rig = result.rig
        position = np.tile(np.asarray(rig.capture_position_mm, float), (k, 1))
        angle = np.full(k, twin.truth.capture_angle_deg)
    else:
        position, angle = twin.heldout_capture_position_mm, twin.heldout_capture_angle_deg
    f = lambda a: np.asarray(a, float)  # noqa: E731  (NumPy: float64 whatever JAX's default)
    return Targets(f(twin.heldout_image_px), f(twin.heldout_depth_mm),
                   f(twin.heldout_hand_angle_deg), f(position), f(angle))  # fmt: skip


def _measured(result, twin) -> tuple[dict[int, np.ndarray], np.ndarray | None]:
    """Each stage's held-out x-y errors, mm, per target; and (three captures) each target's
    group mask for the first capture on the display."""
    if twin.heldout_true_mm is None:
        rows = {r.label: r for r in evaluate(result, twin.truth, _heldout(twin))}
        return ({s: rows[f"stage {s}"].lengths_px * rows[f"stage {s}"].mm_per_px
                 for s in (1, 2)}, None)  # fmt: skip
    rows = {r.label: r for r in evaluate_points(result, twin.truth, _heldout(twin))}
    first = (np.abs(rows["stage 1"].rise_mm) < 1e-6) & (rows["stage 1"].above_mm == 0)
    return {s: rows[f"stage {s}"].xy_mm for s in (1, 2)}, first


def _predicted(result, twin, stage: int):
    stages = fitted_stages(result)
    one, two = stages.stage1, stages.stage2
    P1, P2 = prior_information(one.space), prior_information(two.space)
    noise = result.stage1.noise.noise
    # NumPy float64 in; command_error computes in float64 (JAX's default float32 would not:
    # its pseudo-inverse dropped weak directions, the predictions 15-33 % small).
    e = command_error(StagePoint(noise_part(one.objective), np.asarray(one.x, float), P1),
                      _targets(result, twin), noise, stage=stage,
                      stage2=StagePoint(noise_part(two.objective), np.asarray(two.x, float), P2))
    return float(e.mean_mm), float(e.p95_mm), np.asarray(e.covariance_mm2)


def _coverage_items(result, truth_params: dict[str, float]) -> list[dict]:
    """Each parameter or combination the summary gives a σ for: name, fit, truth, σ and the
    σ's degrees of freedom (``None``: no estimated noise scale enters it)."""
    d = result.diagnostics
    diag = d.stage1
    free = diag.free
    weak = set(d.weak_params)
    own_dof = diag.std_dof or {}
    items = []
    for n in free:
        sd = diag.std.get(n)
        if sd is None or n in weak:
            continue
        items.append({"name": n, "fit": result.stage1.params[n], "truth": truth_params[n],
                      "sigma": sd, "dof": own_dof.get(n)})  # fmt: skip
    cov = np.linalg.pinv(np.asarray(diag.precision, float), hermitian=True)
    for w in diag.weak_directions:
        if not w.determined:
            continue
        names = [p.strip().lstrip("+").strip() for p in w.determined.replace("-", "+").split("+")]
        names = [p for p in names if p]
        if set(names) - set(free) or " - " in w.determined:
            continue
        c = np.array([1.0 if n in names else 0.0 for n in free])
        items.append({"name": " + ".join(names),
                      "fit": float(sum(result.stage1.params[n] for n in names)),
                      "truth": float(sum(truth_params[n] for n in names)),
                      "sigma": float(math.sqrt(max(c @ cov @ c, 0.0))),
                      "dof": _combination_dof(result, c)})  # fmt: skip
    return items


def _combination_dof(result, c: np.ndarray) -> float | None:
    """The degrees of freedom of the σ of ``c · x`` (stage 1's free parameters)."""
    one = fitted_stages(result).stage1
    with float64():
        nu = std_dof(noise_part(one.objective), np.asarray(one.x, float), result.stage1.noise,
                     prior_information(one.space), directions=c[None])[0]  # fmt: skip
    return float(nu) if np.isfinite(nu) else None


def _quantile(item: dict, row: dict) -> float:
    """The 97.5 % quantile of Student's t at the item's σ's degrees of freedom (rows written
    before each σ had its own: the fit's)."""
    dof = item["dof"] if "dof" in item else row["dof"]
    return 1.959963984540054 if dof is None else float(student_t.ppf(0.975, max(dof, 1.0)))


def run_twins(seeds: list[int], model: str, captures: int) -> dict[int, dict | Exception]:
    """Each seed's row, or the error that kept its twin out (a picture the detector cannot
    read, a calibration that failed). The twins are calibrated together, in one
    :func:`~handeye_jax.calibrate_batch` (each result is its own ``calibrate``'s, bit for bit),
    then each is diagnosed; a row's ``seconds`` is its share of the batch plus its own
    simulation and diagnostics."""
    out: dict[int, dict | Exception] = {}
    twins, seconds = {}, {}
    for seed in seeds:
        t0 = time.perf_counter()
        try:
            truth, dh = draw(seed, model, captures)
            twins[seed] = (truth, dh, simulate(truth, PRESETS["paper"], seed, captures=captures))
        except Exception as e:  # e.g. a dot off the picture
            out[seed] = e
        seconds[seed] = time.perf_counter() - t0
    ready = list(twins)
    t0 = time.perf_counter()
    results = calibrate_batch([twins[s][2].dataset for s in ready],
                              [Settings(model=model, seed=s) for s in ready], errors="return",
                              progress=True)  # fmt: skip
    share = (time.perf_counter() - t0) / max(len(ready), 1)
    for seed, result in zip(ready, results, strict=True):
        if isinstance(result, Exception):
            out[seed] = result
            continue
        t0 = time.perf_counter()
        truth, dh, twin = twins[seed]
        row = _row(seed, model, captures, truth, dh, twin, diagnose(result))
        row["seconds"] = seconds[seed] + share + time.perf_counter() - t0
        out[seed] = row
    return {s: out[s] for s in seeds}


def _row(seed: int, model: str, captures: int, truth, dh, twin, result) -> dict:
    truth_params = truth.model if dh is None else dh
    dof = result.stage1.noise.dof
    measured, first = _measured(result, twin)
    stage = result.deploy_stage
    pred = {s: _predicted(result, twin, s) for s in (1, 2)}
    verdict = result.diagnostics.expected
    with float64():
        F_truth = float(fitness(_truth_errors(result, truth_params, model))[0])
    return {
        "seed": seed, "model": model, "captures": captures, "dof": dof,
        "items": _coverage_items(result, truth_params),
        "deploy": stage, "deploy_reason": result.deploy.reason,
        "measured": {s: measured[s].tolist() for s in (1, 2)},
        "first_group": None if first is None else first.tolist(),
        "predicted_mean": {s: pred[s][0] for s in (1, 2)},
        "predicted_p95": {s: pred[s][1] for s in (1, 2)},
        "predicted_cov": {s: pred[s][2].tolist() for s in (1, 2)},
        "verdict_mean": verdict.mean_mm, "verdict_p95": verdict.p95_mm,
        "F1": result.stage1.F, "F1_truth": F_truth,
        "ambiguities": [a.kind for a in result.diagnostics.ambiguities],
        "weak": list(result.diagnostics.weak_params),
    }  # fmt: skip


def _truth_errors(result, params, model):
    from handeye_jax import errors_of, get_model

    cls = get_model(model)
    obj = Stage1Objective(cls, result.data.observations())
    return errors_of(obj, cls.from_dict(params).to_vector())


# -- the tables ----------------------------------------------------------------------------------


def coverage_table(rows: list[dict]) -> list[str]:
    """Per configuration and parameter: how many intervals, how many held the truth."""
    names: dict[str, dict[str, list[bool]]] = {}
    for r in rows:
        cfg = f"{r['model'].upper()}, {r['captures']} capture{'s' if r['captures'] > 1 else ''}"
        for it in r["items"]:
            hit = abs(it["fit"] - it["truth"]) <= _quantile(it, r) * it["sigma"]
            names.setdefault(it["name"], {}).setdefault(cfg, []).append(hit)
            names[it["name"]].setdefault("all", []).append(hit)
    cfgs = sorted({c for v in names.values() for c in v if c != "all"})
    lines = ["| parameter | " + " | ".join(cfgs) + " | all twins |",
             "|---|" + "---|" * (len(cfgs) + 1)]  # fmt: skip
    names["all parameters"] = {c: [h for v in names.values() for h in v.get(c, [])]
                               for c in [*{c for v in names.values() for c in v}]}  # fmt: skip
    order = [*HTMModel.param_names, *DHModel.param_names]
    keys = sorted(names, key=lambda n: (order.index(n) if n in order else
                                        100 if n == "all parameters" else 99, n))  # fmt: skip
    for name in keys:
        cells = []
        for c in [*cfgs, "all"]:
            hits = names[name].get(c)
            cells.append("—" if not hits else f"{100 * np.mean(hits):.1f} % ({len(hits)})")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def error_table(rows: list[dict]) -> list[str]:
    """Per configuration: predicted and measured mean and p95 of the deployed stage."""
    lines = ["| configuration | twins | deployed stage 2 | predicted mean | measured mean | ratio "
             "| predicted p95 | measured p95 | ratio | verdict's mean / measured (first "
             "capture) |", "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    by: dict[str, list[dict]] = {}
    for r in rows:
        by.setdefault(f"{r['model'].upper()}, {r['captures']}", []).append(r)
    for cfg, rs in sorted(by.items()):
        pm = np.mean([r["predicted_mean"][str(r["deploy"])] for r in rs])
        mm = np.mean([np.mean(r["measured"][str(r["deploy"])]) for r in rs])
        covs = np.concatenate([np.asarray(r["predicted_cov"][str(r["deploy"])]) for r in rs])
        with float64():
            pp = float(error_statistics(jnp.asarray(covs))[1])
        mp = float(np.percentile(np.concatenate([r["measured"][str(r["deploy"])] for r in rs]), 95))
        firsts = []
        for r in rs:
            m = np.asarray(r["measured"][str(r["deploy"])])
            g = np.ones(len(m), bool) if r["first_group"] is None else np.asarray(r["first_group"])
            firsts.append((r["verdict_mean"], float(m[g].mean())))
        vm = np.mean([a for a, _ in firsts]) / np.mean([b for _, b in firsts])
        n2 = sum(r["deploy"] == 2 for r in rs)
        lines.append(f"| {cfg} capture(s) | {len(rs)} | {n2} | {pm:.3f} | {mm:.3f} | "
                     f"{pm / mm:.2f} | {pp:.3f} | {mp:.3f} | {pp / mp:.2f} | {vm:.2f} |")
    return lines


def _rounded(x):
    """Rows with six significant digits (the tables print three)."""
    if isinstance(x, float):
        return float(f"{x:.6g}")
    if isinstance(x, list):
        return [_rounded(v) for v in x]
    if isinstance(x, dict):
        return {k: _rounded(v) for k, v in x.items()}
    return x


def main() -> None:
    vectorise_small_loops()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50, help="twins per configuration")
    ap.add_argument("--first", type=int, default=1, help="the first seed")
    ap.add_argument("--configs", nargs="+", choices=sorted(CONFIGS), default=list(CONFIGS))
    ap.add_argument("--rows", type=Path, default=ROWS, help="JSON of every twin's row")
    ap.add_argument("--results", type=Path, default=RESULTS, help="Markdown file to update")
    ap.add_argument("--append", action="store_true", help="add to the rows already in --rows")
    ap.add_argument("--quick", action="store_true", help="3 twins per configuration, no files")
    args = ap.parse_args()
    n = 3 if args.quick else args.seeds
    rows = json.loads(args.rows.read_text()) if args.append and args.rows.exists() else []
    done = {(r["model"], r["captures"], r["seed"]) for r in rows}
    t0 = time.perf_counter()
    for cfg in args.configs:
        model, captures = CONFIGS[cfg]
        seeds = [s for s in range(args.first, args.first + n) if (model, captures, s) not in done]
        for seed, row in run_twins(seeds, model, captures).items():
            if isinstance(row, Exception):  # a twin the detector cannot read: not counted
                print(f"{cfg} seed {seed}: skipped ({type(row).__name__}: {row})", flush=True)
                continue
            rows.append(json.loads(json.dumps(row)))
            print(f"{cfg} seed {seed}: deploy {row['deploy']}, {len(row['items'])} intervals, "
                  f"{row['seconds']:.1f} s", flush=True)  # fmt: skip
        if not args.quick:
            args.rows.parent.mkdir(parents=True, exist_ok=True)
            args.rows.write_text(json.dumps(_rounded(rows), separators=(",", ":")))
    elapsed = time.perf_counter() - t0
    rows = [json.loads(json.dumps(r)) for r in rows]
    text = "\n".join([
        HEADING, "",
        f"command: python benchmarks/coverage.py --seeds {n} --first {args.first} --configs "
        f"{' '.join(args.configs)}",
        f"machine: {platform.machine()}, {elapsed:.0f} s this run; {len(rows)} twins; rows in "
        f"{args.rows.name}",
        "", "Coverage of the reported 95 % intervals (± t·σ), per parameter (twins):", "",
        *coverage_table(rows), "",
        "Touching error of the stage deployed, predicted (covariance and noise model) against "
        "measured, held-out targets, mm:", "", *error_table(rows), "",
        "The stage deployed against the better of the two: benchmarks/stage_choice.py, on "
        "these twins.",
    ])  # fmt: skip
    print(text)
    if not args.quick:
        write_section(args.results, HEADING, text)


if __name__ == "__main__":
    main()
