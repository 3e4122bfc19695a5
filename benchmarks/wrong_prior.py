"""Issue 26: with a prior wrong in one parameter, does the summary name that parameter first?

    python benchmarks/wrong_prior.py [--seeds 1 2 3 4 5] [--params xt yt gamma_t gamma_c]
                                     [--k 4] [--captures 1] [--results PATH]

For each seed S and parameter P: the twin of ``simulate old --seed S`` (``paper`` noise) is
calibrated with the defaults: the old result. Then the pen changes (``change_truth(…, "pen",
S)``) and, unannounced, P moves by 5 of its prior σ (the old posterior's marginal over the
parameters outside the pen), or nothing else moves (the prior right: a row of its own); the
new twin (noise seed 1000 + S) is cut to k landmarks (k = 4:
the corners, m = 0, 2, 6, 8) and recalibrated from the old result with ``--refit pen``: every
other parameter takes the old posterior as its prior. The summary names a moved prior
parameter in its checks, largest pull first, the parameters that only follow it (their
pull vanishes once it moves) on the same line, and stage 2's prior checks, when stage 1 has
one, on one line that follows it. Counted: the fits whose first prior check names P, and the
parameters flagged beside it (a check of their own). With ``--captures 3`` the old result
comes from three pictures (two-pixel dots, as ``coverage.py``'s three-capture twins), whose
fit has no weak direction: every prior parameter is tested.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

from handeye_jax import (
    PRESETS,
    Settings,
    calibrate,
    change_truth,
    diagnose,
    draw_truth,
    recalibrate,
    simulate,
    vectorise_small_loops,
)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from recalibration import NEW_SEED, SUBSETS, prior_sigma, subset  # noqa: E402
from twin_study import write_section  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
HEADING = "## A prior wrong in one parameter: named first (issue 26)"
HEADING_3 = "## A prior wrong in one parameter, the old result from three captures (issue 26)"
SIGMAS = 5.0


def run(seed: int, params, k: int, captures: int = 1) -> dict:
    truth = draw_truth(seed, dot_px=1.0 if captures == 1 else 2.0)
    # As the command line makes it: diagnosed (its weak parameters are known to the prior).
    old_twin = simulate(truth, PRESETS["paper"], seed, captures=captures)
    old = diagnose(calibrate(old_twin.dataset, Settings(seed=seed)))
    out = {}
    for p in [*params, None]:  # None: nothing else moved, the prior right
        sigma = None if p is None else prior_sigma(old, p, "pen")
        changed = change_truth(truth, "pen", seed)
        model = dict(changed.model)
        if p is not None:
            model[p] += SIGMAS * sigma
        twin = simulate(replace(changed, model=model), PRESETS["paper"], NEW_SEED + seed)
        r = recalibrate(subset(twin.dataset, SUBSETS[k]), old, ("pen",), Settings(seed=seed))
        checks = [w for w in r.warnings if w.kind == "prior"]
        pulls = {q.param: q for q in r.stage1.prior.pulls}
        out[p] = {
            "sigma": sigma, "pull": None if p is None else pulls[p].pull,
            "first": checks[0].param if checks else None,
            "beside": [w.param for w in checks[1:] if w.param is not None],
            "stage2_following": any(w.param is None for w in checks),
            "following": [q.param for q in pulls.values() if q.follows],
            "text": checks[0].text if checks else "",
            "checks": len(checks),
        }  # fmt: skip
    return out


def main() -> None:
    vectorise_small_loops()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--params", nargs="+", default=["xt", "yt", "gamma_t", "gamma_c"])
    ap.add_argument("--k", type=int, choices=sorted(SUBSETS), default=4)
    ap.add_argument("--captures", type=int, choices=[1, 3], default=1,
                    help="pictures behind the old result")
    ap.add_argument("--results", type=Path, default=RESULTS)
    args = ap.parse_args()
    t0 = time.perf_counter()
    runs = {s: run(s, args.params, args.k, args.captures) for s in args.seeds}
    heading = HEADING if args.captures == 1 else HEADING_3
    lines = [
        heading, "",
        f"command: python benchmarks/wrong_prior.py --seeds {' '.join(map(str, args.seeds))} "
        f"--params {' '.join(args.params)} --k {args.k}"
        + ("" if args.captures == 1 else f" --captures {args.captures}"),
        f"machine: {platform.machine()}; {time.perf_counter() - t0:.0f} s; the pen changed and "
        f"one parameter moved {SIGMAS:g} prior σ; recalibrate --refit pen on k = {args.k} "
        f"touches (m = {', '.join(map(str, SUBSETS[args.k]))})", "",
        "| moved | prior σ | named first | its pull (mean, min) | flagged beside it per fit | "
        "shown as following it per fit | stage 2's checks on one line, following |",
        "|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for p in args.params:
        rows = [runs[s][p] for s in args.seeds]
        first = sum(r["first"] == p for r in rows)
        pulls = [abs(r["pull"]) for r in rows]
        beside = sum(len(r["beside"]) for r in rows) / len(rows)
        follow = sum(len(r["following"]) for r in rows) / len(rows)
        lines.append(f"| {p} | {rows[0]['sigma']:.3g} | {first} of {len(rows)} | "
                     f"{sum(pulls) / len(pulls):.1f}, {min(pulls):.1f} | {beside:.1f} | "
                     f"{follow:.1f} | {sum(r['stage2_following'] for r in rows)} of "
                     f"{len(rows)} |")  # fmt: skip
    right = [runs[s][None] for s in args.seeds]
    flagged = sum(r["checks"] > 0 for r in right)
    lines.append(f"| none (the prior right) | – | – | – | {flagged} of {len(right)} fits with a "
                 f"check ({sum(r['checks'] for r in right)} in all) | – | – |")
    example = next((runs[s][args.params[0]]["text"] for s in args.seeds
                    if runs[s][args.params[0]]["text"]), "")  # fmt: skip
    if example:
        lines += ["", f"The check, e.g. (seed {args.seeds[0]}): `{example}`"]
    text = "\n".join(lines)
    print(text)
    write_section(args.results, heading, text)


if __name__ == "__main__":
    main()
