"""Issue 26: does the stage ``calibrate`` deploys do as well as the better of the two?

    python benchmarks/stage_choice.py [--seeds 5] [--first 1] [--rows PATH] [--run]
                                      [--results PATH] [--out PATH]

20 twins by default: seeds ``first`` … ``first + seeds − 1`` of each configuration of
``benchmarks/coverage.py`` (HTM and DH; one capture and three; ``paper`` noise, rendered
pictures, landmarks detected; calibrated with the defaults, the stage to deploy chosen by
leave-one-out over touches). For each twin: both stages' measured mean touching error on its
held-out targets (command against the true command), and the stage deployed. The acceptance:
the deployed stage's error is on average within 1.02× of the better stage's.

The twins are coverage.py's: their rows are read from ``--rows`` (``coverage.py`` writes them);
``--run`` computes the missing ones (``coverage.run_twins``) and adds them to the file. The
table goes to ``--results`` (``benchmarks/RESULTS.md``) and the rows used to ``--out``
(``results/stage_choice.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from coverage import CONFIGS, ROWS  # noqa: E402
from twin_study import write_section  # noqa: E402

RESULTS = HERE / "RESULTS.md"
OUT = HERE / "results" / "stage_choice.json"
HEADING = "## The stage deployed against the better of the two (issue 26)"
TARGET = 1.02


def measure(rows: list[dict]) -> list[dict]:
    """Per twin: each stage's measured held-out mean, mm, the deployed one and the better."""
    out = []
    for r in rows:
        s1, s2 = (float(np.mean(r["measured"][k])) for k in ("1", "2"))
        deployed = s2 if r["deploy"] == 2 else s1
        out.append({"model": r["model"], "captures": r["captures"], "seed": r["seed"],
                    "deploy": r["deploy"], "stage1_mm": s1, "stage2_mm": s2,
                    "deployed_mm": deployed, "better_mm": min(s1, s2),
                    "reason": r["deploy_reason"]})  # fmt: skip
    return out


def table(m: list[dict]) -> list[str]:
    lines = ["| configuration | twins | deployed stage 2 | stage 1 mm | stage 2 mm | deployed mm "
             "| better mm | deployed / better (ratio of means) | mean of ratios | worst ratio |",
             "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    groups: dict[str, list[dict]] = {}
    for r in m:
        groups.setdefault(f"{r['model'].upper()}, {r['captures']} capture(s)", []).append(r)
    groups["all"] = m
    for name, rs in groups.items():
        a = {k: np.array([r[k] for r in rs]) for k in ("stage1_mm", "stage2_mm", "deployed_mm",
                                                        "better_mm")}  # fmt: skip
        ratio = a["deployed_mm"] / a["better_mm"]
        lines.append(
            f"| {name} | {len(rs)} | {sum(r['deploy'] == 2 for r in rs)} | "
            f"{a['stage1_mm'].mean():.3f} | {a['stage2_mm'].mean():.3f} | "
            f"{a['deployed_mm'].mean():.3f} | {a['better_mm'].mean():.3f} | "
            f"{a['deployed_mm'].mean() / a['better_mm'].mean():.3f} | {ratio.mean():.3f} | "
            f"{ratio.max():.3f} |"
        )  # fmt: skip
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="twins per configuration")
    ap.add_argument("--first", type=int, default=1, help="the first seed")
    ap.add_argument("--rows", type=Path, default=ROWS, help="coverage.py's rows (JSON)")
    ap.add_argument("--run", action="store_true", help="compute the twins the rows lack")
    ap.add_argument("--results", type=Path, default=RESULTS, help="Markdown file to update")
    ap.add_argument("--out", type=Path, default=OUT, help="JSON of the rows the table used")
    args = ap.parse_args()
    rows = json.loads(args.rows.read_text()) if args.rows.exists() else []
    have = {(r["model"], r["captures"], r["seed"]): r for r in rows}
    wanted = [(model, captures, s) for model, captures in CONFIGS.values()
              for s in range(args.first, args.first + args.seeds)]  # fmt: skip
    missing = [w for w in wanted if w not in have]
    if missing and not args.run:
        sys.exit(f"{args.rows}: no rows for {len(missing)} twins (e.g. {missing[0]}); run "
                 "benchmarks/coverage.py first, or pass --run")  # fmt: skip
    if missing:
        from coverage import run_twins

        from handeye_jax import vectorise_small_loops

        vectorise_small_loops()
        for model, captures in {(k[0], k[1]) for k in missing}:
            seeds = [k[2] for k in missing if k[:2] == (model, captures)]
            for seed, row in run_twins(seeds, model, captures).items():
                if isinstance(row, Exception):
                    sys.exit(f"{model}, {captures} capture(s), seed {seed}: {row}")
                have[(model, captures, seed)] = json.loads(json.dumps(row))
            args.rows.write_text(json.dumps(list(have.values())))
    m = measure([have[w] for w in wanted])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(m, indent=1))
    where = args.out.resolve()
    where = where.relative_to(HERE) if where.is_relative_to(HERE) else where
    ratio = np.mean([r["deployed_mm"] for r in m]) / np.mean([r["better_mm"] for r in m])
    text = "\n".join([
        HEADING, "",
        f"command: python benchmarks/stage_choice.py --seeds {args.seeds} --first {args.first}"
        f" (the twins of benchmarks/coverage.py; rows in {where})",
        "", f"{len(m)} twins; the deployed stage's mean held-out touching error is "
        f"{ratio:.3f}× the better stage's (target ≤ {TARGET}).", "", *table(m),
    ])  # fmt: skip
    print(text)
    write_section(args.results, HEADING, text)


if __name__ == "__main__":
    main()
