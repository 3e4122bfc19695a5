"""Evaluation trials and their file, ``handeye-jax.trials/1`` (JSON; px and mm).

A trial is one pass over the targets: the robot touches each target with the pen and the
tablet measures how far from it the pen landed. Its mean touching error, in tablet px and in
mm (eq. 9), is one column of the paper's Tables 9 and 12; their "Average" column is the mean
over trials. Trials are grouped by ``label`` (e.g. ``"stage 1"``, ``"stage 2"``)::

    {"format": "handeye-jax.trials/1",
     "tablet": {"ppi": 267.0, "scale": 2.0, "mm_per_px": 0.19026},
     "trials": [{"trial": 1, "label": "stage 2", "run_id": "...", "targets": "dataset",
                 "saved_utc": "2026-11-22T03:00:00Z", "result": {...} or null,
                 "mean_px": 5.14, "max_px": 8.1, "mean_mm": 0.98, "max_mm": 1.54,
                 "touches": [{"m": 0, "target_px": [400.0, 150.0], "touch_px": [403.0, 151.0],
                              "error_px": [3.0, 1.0], "distance_px": 3.16,
                              "distance_mm": 0.60, "pointer_type": "pen"}, ...]}, ...]}
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Any

import numpy as np

from .._core import Reader, describe, load_json, write_output
from ..geometry import mm_per_tablet_px
from ._log import printable
from ._posts import EvaluationPost

FORMAT = "handeye-jax.trials/1"
# A trials file the server may read: posts keep it under ~3.3 MB (100 trials of 100 touches).
MAX_FILE_BYTES = 16 * 1024 * 1024


def new_trials(ppi: float, scale: float) -> dict[str, Any]:
    """An empty trials document for a tablet of ``ppi`` px per inch at display ``scale``."""
    return {
        "format": FORMAT,
        "tablet": {"ppi": ppi, "scale": scale, "mm_per_px": mm_per_tablet_px(ppi, scale)},
        "trials": [],
    }


def load_trials(path: str | Path, ppi: float, scale: float) -> dict[str, Any]:
    """Read a trials file, or a new document when ``path`` does not exist.

    Raises :class:`InputError` when the file is unreadable, over 16 MiB, not this format, or
    was measured on a tablet with another ppi or scale (its mm figures would not be comparable).
    """
    path = Path(path)
    if not path.exists():
        return new_trials(ppi, scale)
    r = Reader(path)
    doc = load_json(path, cap=MAX_FILE_BYTES, what="trials")
    if not isinstance(doc, dict):
        r.fail("", "must be a JSON object")
    if doc.get("format") != FORMAT:
        r.fail("format", f"expected {FORMAT!r} (got {describe(doc.get('format'))})")
    for key in ("tablet", "trials"):
        if key not in doc:
            r.fail(key, "missing")
    tablet = r.table(doc["tablet"], "tablet", ("ppi", "scale", "mm_per_px"))
    for key, want in (("ppi", ppi), ("scale", scale)):
        got = r.number(tablet[key], f"tablet.{key}", positive=True)
        if got != want:
            r.fail(f"tablet.{key}", f"trials were measured at {got}, this tablet is {want}")
    if not isinstance(doc.get("trials"), list):
        r.fail("trials", f"must be an array (got {describe(doc.get('trials'))})")
    for i, t in enumerate(doc["trials"]):
        if not isinstance(t, dict):
            r.fail(f"trials[{i}]", "must be an object")
        for key in ("mean_px", "max_px", "mean_mm", "max_mm"):
            r.number(t.get(key), f"trials[{i}].{key}")
        if not isinstance(t.get("label"), str) or not isinstance(t.get("run_id"), str):
            r.fail(f"trials[{i}]", "needs a string label and run_id")
    return doc


def make_trial(
    post: EvaluationPost, doc: dict[str, Any], result: dict[str, Any] | None = None
) -> dict[str, Any]:
    """The trial record for a posted trial: errors per touch and their mean and max, px and mm.

    Args:
        post: the validated post (CSS px).
        doc: the trials document it joins (gives the trial number and mm per px).
        result: what was deployed (the result file's path, model, seed), or ``None``.
    """
    mm = doc["tablet"]["mm_per_px"]
    error = post.touch_px - post.target_px
    dist = np.linalg.norm(error, axis=1)
    number = 1 + sum(t["label"] == post.label for t in doc["trials"])
    touches = [
        {
            "m": i,
            "target_px": post.target_px[i].tolist(),
            "touch_px": post.touch_px[i].tolist(),
            "error_px": error[i].tolist(),
            "distance_px": float(dist[i]),
            "distance_mm": float(dist[i] * mm),
            "pointer_type": post.pointer_types[i],
        }
        for i in range(len(dist))
    ]
    return {
        "trial": number,
        "label": post.label,
        "run_id": post.run_id,
        "targets": post.targets,
        "saved_utc": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "result": result,
        "mean_px": float(dist.mean()),
        "max_px": float(dist.max()),
        "mean_mm": float(dist.mean() * mm),
        "max_mm": float(dist.max() * mm),
        "touches": touches,
    }


def find_trial(doc: dict[str, Any], run_id: str) -> dict[str, Any] | None:
    """The trial saved under ``run_id``, if any (a resent post is saved once)."""
    return next((t for t in doc["trials"] if t["run_id"] == run_id), None)


def save_trials(doc: dict[str, Any], path: str | Path) -> None:
    """Write the trials document atomically: complete or untouched.

    Raises :class:`InputError` naming ``path`` (not the temporary file) and the reason when
    it cannot be written.
    """
    write_output(path, json.dumps(doc, indent=1, allow_nan=False) + "\n")


def summarise(doc: dict[str, Any]) -> list[dict[str, Any]]:
    """Tables 9 and 12: per label, each trial's mean and max error and the average, px and mm."""
    out = []
    for label in dict.fromkeys(t["label"] for t in doc["trials"]):
        rows = [t for t in doc["trials"] if t["label"] == label]
        keys = ("mean_px", "max_px", "mean_mm", "max_mm")
        out.append(
            {
                "label": label,
                "trials": [{"trial": t["trial"], **{k: t[k] for k in keys}} for t in rows],
                "average": {k: float(np.mean([t[k] for t in rows])) for k in keys},
            }
        )
    return out


def format_summary(doc: dict[str, Any]) -> str:
    """The summary as text, one block per label, like Tables 9 and 12; each label's
    non-printable characters (ESC, a lone surrogate) escaped (``\\x1b``)."""
    lines = []
    for s in summarise(doc):
        heads = [f"{t['trial']:>6d}" for t in s["trials"]]
        lines.append(f"{printable(s['label'])}: mean touching error per trial")
        lines.append("trial        " + " ".join(heads) + "  average")
        for unit in ("px", "mm"):
            cells = [f"{t[f'mean_{unit}']:6.2f}" for t in s["trials"]]
            avg = s["average"][f"mean_{unit}"]
            lines.append(f"mean in {unit}   " + " ".join(cells) + f"  {avg:7.2f}")
        for unit in ("px", "mm"):
            cells = [f"{t[f'max_{unit}']:6.2f}" for t in s["trials"]]
            avg = s["average"][f"max_{unit}"]
            lines.append(f"max in {unit}    " + " ".join(cells) + f"  {avg:7.2f}")
    return "\n".join(lines)
