"""The paper's data with the robot moved, calibrated with no search ranges (issue 25's first
acceptance).

    python benchmarks/moved_paper.py [--quick] [--out benchmarks/results/moved_paper.md]

The published data with the robot's base frame shifted +300 mm in x (hand positions and
capture pose), and separately turned 90° about its z axis (the capture and touch poses turned
likewise, :func:`handeye_jax.moved_base`), calibrated with the default search (no ``[search]``)
under the paper's loss (``l1``):
F1st against the paper's 1.673860 mm; and with the paper's ranges (``search="paper"``) for
contrast. Both models, and the data unmoved. The table goes to standard output and ``--out``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import sys
import time
from pathlib import Path

from handeye_jax import Settings, calibrate, load_dataset, moved_base, vectorise_small_loops

PAPER = Path(__file__).resolve().parents[1] / "data" / "paper2023.toml"
OUT = Path(__file__).resolve().parent / "results" / "moved_paper.md"
PAPER_F1ST = 1.673860


def moved_cases() -> list[tuple[str, object]]:
    """The published data, shifted +300 mm in x, and turned 90° about z, with their labels."""
    paper = load_dataset(PAPER)
    return [("as published", paper), ("shifted +300 mm in x", moved_base(paper, (300.0, 0.0))),
            ("turned 90° about z", moved_base(paper, turn_deg=90.0))]  # fmt: skip


#: ``--quick``'s rows: each move, model and search once (a smoke test of the table).
QUICK_ROWS = (("shifted +300 mm in x", "htm", "estimate"), ("turned 90° about z", "dh", "paper"))


def moved_paper_rows(settings: Settings, only: tuple[tuple[str, str, str], ...] = ()) -> list[str]:
    """The table of the paper's data moved, both models and presets (``only``: just these
    rows, by data label, model and search)."""
    cases = moved_cases()
    rows = ["| data | model | search | F1st mm | F2nd mm | F1st = 1.673860 | bound warnings | s |",
            "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for label, ds in cases:
        for model in ("htm", "dh"):
            for preset in ("estimate", "paper"):
                if only and (label, model, preset) not in only:
                    continue
                t0 = time.perf_counter()
                r = calibrate(ds, dataclasses.replace(settings, model=model, search=preset))
                bounds = sum(w.kind == "bound" for w in r.warnings)
                seconds = time.perf_counter() - t0
                same = "yes" if abs(r.stage1.F - PAPER_F1ST) <= 1e-6 else "no"
                rows.append(f"| {label} | {model.upper()} | {preset} | {r.stage1.F:.6f} | "
                            f"{r.stage2.F:.6f} | {same} | {bounds} | {seconds:.1f} |")  # fmt: skip
    return rows


#: The parameters of the hand (camera mount and pen), which no move of the base changes.
HAND_PARAMS = ("xc", "yc", "alpha_c", "beta_c", "gamma_c", "xp", "yp")


def default_loss_rows() -> list[str]:
    """The moves at the true defaults (HTM, maximum likelihood): each against the unmoved
    data's fit, whose optimum is the ML one, not the paper's F1st."""
    cases = moved_cases()
    rows = ["| data | F1st mm | F2nd mm | abs ΔF1st against unmoved, mm | largest Δ of the hand's "
            "parameters (mm, deg) | bound warnings | s |", "|---|---|---|---|---|---|---|"]
    ref = None
    for label, ds in cases:
        t0 = time.perf_counter()
        r = calibrate(ds, Settings())
        seconds = time.perf_counter() - t0
        ref = ref or r
        dp = max(abs(r.stage1.params[k] - ref.stage1.params[k]) for k in HAND_PARAMS)
        bounds = sum(w.kind == "bound" for w in r.warnings)
        rows.append(f"| {label} | {r.stage1.F:.6f} | {r.stage2.F:.6f} | "
                    f"{abs(r.stage1.F - ref.stage1.F):.1e} | {dp:.1e} | {bounds} | "
                    f"{seconds:.1f} |")  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=OUT, help="the table (Markdown)")
    ap.add_argument("--quick", action="store_true",
                    help="smaller DE, two of the rows; the table not kept")
    ap.add_argument("--default-loss", action="store_true",
                    help="the moves at the true defaults (maximum likelihood) instead")
    args = ap.parse_args(argv)
    vectorise_small_loops()
    if args.default_loss:
        print("\n".join(default_loss_rows()))
        return 0
    # The paper's F (loss l1): where the search looks is the question; the default loss, maximum
    # likelihood, starts from the optimum the search finds.
    settings = Settings(loss="l1")
    only: tuple[tuple[str, str, str], ...] = ()
    if args.quick:  # the test suite's budget (tests/common.py): its compiled programs serve
        settings, args.out = Settings(population=200, generations=400, loss="l1"), None
        only = QUICK_ROWS
    lines = [f"# The paper's data moved, {time.strftime('%Y-%m-%d')}",
             f"command: python benchmarks/moved_paper.py {' '.join(sys.argv[1:])}",
             f"machine: {platform.machine()}, {os.cpu_count()} cores; load average at start "
             f"{os.getloadavg()[0]:.2f}",
             f"\nDefaults but the model and search (the paper's F1st {PAPER_F1ST} mm; the "
             "HTM's, as the DH chain holds this rig less well):\n",
             *moved_paper_rows(settings, only)]  # fmt: skip
    text = "\n".join(lines) + "\n"
    print(text, end="")
    if args.out is not None:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    main()
