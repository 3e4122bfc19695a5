"""Batch throughput: ``calibrate_batch`` against a Python loop of ``calibrate()``, side by side
in one process, after compilation.

    python benchmarks/batch_throughput.py [--sizes 20 50] [--devices 2] [--preset paper]
                                          [--population N --generations G] [--rounds R]
                                          [--processes 2]

For each batch size B, B twins of the preset are simulated (the first B seeds from 1 whose
picture shows every landmark; the others are counted and printed; the paper's 3×3 grid,
one capture), then timed in turn, round after round: the loop (``calibrate`` of each twin),
the batch on one device and, with ``--devices 2``, the batch on two host devices
(``XLA_FLAGS=--xla_force_host_platform_device_count``, set here before JAX starts). Each is
run once first (the loop: one ``calibrate``; a batch: on as few twins as make every wave size
it will meet) so that every program is compiled before the clock starts. Prints a Markdown
table: seconds per problem, the speed-up of each batch over the loop, the largest difference
of F (both stages, mm) and of any parameter between each batch result and its own loop
result, and the process's peak memory.

With ``--processes P`` (and ``--devices 1``), each batch is then also run split over P
processes of this script under ``jax.distributed`` on 127.0.0.1 (one device each), each
timed after a first run that compiles; process 0 reports its wall time per problem.
"""

from __future__ import annotations

import argparse
import inspect
import os
import platform
import resource
import sys
import time


def _args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[20, 50], help="batch sizes B")
    p.add_argument("--devices", type=int, default=2, help="host devices (1 or more)")
    p.add_argument("--preset", default="paper", help="the twins' noise preset")
    p.add_argument("--population", type=int, default=None, help="DE population (default: 500)")
    p.add_argument("--generations", type=int, default=None, help="DE generations (default: 3000)")
    p.add_argument("--rounds", type=int, default=1, help="timed rounds of each candidate")
    p.add_argument("--processes", type=int, default=1, help="also split over this many")
    p.add_argument("--worker", type=str, default=None, help=argparse.SUPPRESS)  # PORT:ID
    return p.parse_args()


ARGS = _args()
# Before JAX starts: the host devices the batch is sharded over.
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                           f" --xla_force_host_platform_device_count={ARGS.devices}").strip()

import jax  # noqa: E402
import numpy as np  # noqa: E402

if ARGS.worker:  # one of --processes processes: before JAX's first computation
    _port, _id = ARGS.worker.split(":")
    jax.distributed.initialize(f"127.0.0.1:{_port}", num_processes=ARGS.processes,
                               process_id=int(_id))  # fmt: skip

from handeye_jax import (  # noqa: E402
    PRESETS,
    Settings,
    calibrate,
    calibrate_batch,
    draw_truth,
    problem_mesh,
    simulate,
    vectorise_small_loops,
)
from handeye_jax.vision import BlobCountError  # noqa: E402

vectorise_small_loops()  # as the command line does, before JAX's first computation


def twins(b: int, preset: str) -> list:
    """The first ``b`` seeds' twins whose rendered picture shows every landmark (a drawn rig
    can put a dot off the picture or onto another; such a seed is skipped and counted)."""
    out, s = [], 0
    while len(out) < b:
        s += 1
        try:
            out.append(simulate(draw_truth(s), PRESETS[preset], s, n_heldout=1).dataset.replace(
                name=f"twin{s}"))
        except BlobCountError:
            SKIPPED.append(s)
    return out


SKIPPED: list[int] = []  # the seeds whose picture did not show every landmark


def numbers(results) -> np.ndarray:
    """Each result's F of both stages and every parameter, one row per problem."""
    return np.array([[r.stage1.F, r.stage2.F, *r.stage1.params.values(),
                      *r.stage2.params.values()] for r in results])  # fmt: skip


def _wave_shapes(data: list, devices: int) -> list:
    """As few of the problems as give a batch of ``data`` every wave size it will meet (a full
    wave and the remainder's), so that a run on them compiles every program it needs."""
    per_wave = inspect.signature(calibrate_batch).parameters["wave"].default * devices
    return data if len(data) <= per_wave else data[:per_wave] + data[: len(data) % per_wave]


def run_size(b: int, settings: Settings, rounds: int) -> dict:
    data = twins(b, ARGS.preset)
    meshes = {f"batch, {k} device{'s' * (k > 1)}": problem_mesh(jax.devices()[:k])
              for k in sorted({1, ARGS.devices})}  # fmt: skip
    candidates = {"loop of calibrate()": lambda: [calibrate(d, settings) for d in data]}
    for name, mesh in meshes.items():
        candidates[name] = lambda mesh=mesh: calibrate_batch(data, settings, mesh=mesh)
    calibrate(data[0], settings)  # compiles the loop's programs (every twin has its shape)
    for mesh in meshes.values():  # compiles the batches' programs: a wave of each size
        calibrate_batch(_wave_shapes(data, mesh.devices.size), settings, mesh=mesh)
    out = {}
    times = {name: [] for name in candidates}
    for _ in range(rounds):
        for name, fn in candidates.items():
            t0 = time.perf_counter()
            out[name] = fn()
            times[name].append((time.perf_counter() - t0) / b)
    ref = numbers(out["loop of calibrate()"])
    rows = {}
    for name in candidates:
        got = numbers(out[name])
        rows[name] = {
            "s_per_problem": min(times[name]), "all_s": times[name],
            "dF_mm": float(np.max(np.abs(got[:, :2] - ref[:, :2]))),
            "dparam": float(np.max(np.abs(got[:, 2:] - ref[:, 2:]))),
        }
    return rows


def run_processes(b: int) -> float:
    """Seconds per problem of the batch split over ``--processes`` processes (process 0's)."""
    import socket
    import subprocess

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    argv = [sys.executable, __file__, "--sizes", str(b), "--devices", "1", "--preset",
            ARGS.preset, "--processes", str(ARGS.processes)]  # fmt: skip
    for name in ("population", "generations"):
        if getattr(ARGS, name):
            argv += [f"--{name}", str(getattr(ARGS, name))]
    procs = [subprocess.Popen([*argv, "--worker", f"{port}:{i}"], stdout=subprocess.PIPE,
                              text=True) for i in range(ARGS.processes)]  # fmt: skip
    outs = [p.communicate()[0] for p in procs]
    line = [x for x in outs[0].splitlines() if x.startswith("WORKER ")][0]
    return float(line.split()[1])


def worker() -> None:
    """One process of a split batch: compile, then time one run."""
    b = ARGS.sizes[0]
    data = twins(b, ARGS.preset)
    d = Settings()
    settings = Settings(population=ARGS.population or d.population,
                        generations=ARGS.generations or d.generations)  # fmt: skip
    calibrate_batch(data, settings)
    t0 = time.perf_counter()
    calibrate_batch(data, settings)
    print(f"WORKER {(time.perf_counter() - t0) / b}")


def main() -> None:
    d = Settings()
    settings = Settings(population=ARGS.population or d.population,
                        generations=ARGS.generations or d.generations)  # fmt: skip
    print(f"# batch throughput: {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, jax {jax.__version__}, {jax.device_count()} host devices; "
          f"preset {ARGS.preset}, population {settings.population}, generations "
          f"{settings.generations}, restarts {settings.restarts}, {ARGS.rounds} round(s)")
    print("| B | candidate | s / problem (each round) | speed-up over the loop | "
          "max abs ΔF (mm) | max abs Δ parameter |")
    print("|---|---|---|---|---|---|")
    for b in ARGS.sizes:
        rows = run_size(b, settings, ARGS.rounds)
        loop = rows["loop of calibrate()"]["s_per_problem"]
        for name, r in rows.items():
            each = ", ".join(f"{t:.3f}" for t in r["all_s"])
            print(f"| {b} | {name} | {r['s_per_problem']:.3f} ({each}) | "
                  f"{loop / r['s_per_problem']:.1f}× | {r['dF_mm']:.1e} | {r['dparam']:.1e} |")
        if ARGS.processes > 1:
            t = run_processes(b)
            print(f"| {b} | batch, {ARGS.processes} processes × 1 device | {t:.3f} | "
                  f"{loop / t:.1f}× | (tested equal: tests/test_batch.py) | |")
        sys.stdout.flush()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\npeak memory (whole process): {peak:.0f} MiB")
    if SKIPPED:
        print(f"seeds skipped (a landmark not in the picture): {len(SKIPPED)}: {SKIPPED}")


if __name__ == "__main__":
    worker() if ARGS.worker else main()
