"""XLA compiler options for this package's compiled programs on the CPU.

Two kinds of program, two sets of options. Each set applies only to the programs compiled
with it, never to the user's own JAX code. The options are probed once: one this XLA does not
know (or any, on a backend that is not the CPU) is left out, and JAX's default applies.

* **The DE's loop** runs thousands of times, so it is compiled for speed. XLA's CPU backend
  hands some fused reductions to YNNPACK; for the objectives here (a few hundred float64
  operations per member, reduced over a handful of landmarks) that is slower than XLA's own
  loops, because it stores every intermediate array of the reduction and reads it back.
  Turning it off made a DE generation at N = 10,000 about 1.4× faster on the 2-core CPU this
  was tuned on (``benchmarks/de_throughput.py`` measures it).
* **Everything else** (the LM polish, the DE's initial population, the diagnostics' batched
  Jacobians, the stage reports) runs a handful of times per calibration, so its compile time
  is what a user waits for. These are compiled with XLA's classic loop emitters and without
  LLVM's optimisation passes (level 0), or at level 1 for a program called once per
  iteration of a host loop. On the diagnostics' stage-1 Jacobians, compilation takes 0.94 s
  at full optimisation, 0.59 s at level 1 and 0.30 s at level 0, and a call 0.57, 0.58 and
  1.39 ms. With the other changes of ``benchmarks/RESULTS.md``, a first calibration from the
  shell went from 12.7 s to 7.7–9.3 s (``benchmarks/first_call.py``).

One more setting cannot be scoped to a program: LLVM's loop vectoriser leaves any loop of
fewer than 16 iterations scalar, and XLA's CPU code for a population is full of them (the 12
parameters of a member, the 9 landmarks). :func:`vectorise_small_loops` lowers that limit to
4 for the whole process, through ``XLA_FLAGS``, so it must run before JAX's first computation.
The command line, the benchmarks and the notebooks call it; a library user may call it
first thing. It changes which loops use SIMD instructions, not the arithmetic: the DE's
populations are bit-identical with and without it (``tests/test_de.py``). On the 2-core
machine it made a DE generation at N = 10,000 about 1.3× faster (``benchmarks/RESULTS.md``).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax

_NO_YNN_FUSION: dict[str, Any] = {"xla_cpu_experimental_ynn_fusion_type": ""}
_CLASSIC_EMITTERS: dict[str, Any] = {"xla_cpu_use_fusion_emitters": False}
_LLVM_OPT_LEVEL = "xla_backend_optimization_level"
SMALL_LOOPS_FLAG = "--xla_backend_extra_options=-vectorizer-min-trip-count=4"


def _accepts(options: dict[str, Any]) -> bool:
    try:
        jax.jit(lambda x: x + 1, compiler_options=options).lower(1.0).compile()
    except Exception:  # an XLA without an option rejects it by name
        return False
    return True


@functools.cache
def _supported() -> frozenset[str]:
    """The options this XLA accepts: one small compilation, unless some are rejected."""
    if jax.default_backend() != "cpu":
        return frozenset()
    every = {**_NO_YNN_FUSION, **_CLASSIC_EMITTERS, _LLVM_OPT_LEVEL: 0}
    if _accepts(every):
        return frozenset(every)
    return frozenset(k for k, v in every.items() if _accepts({k: v}))


def _keep(options: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in options.items() if k in _supported()}


def loop_compiler_options() -> dict[str, Any]:
    """Options for a hot loop (the DE's generations): those this XLA has."""
    return _keep(_NO_YNN_FUSION)


def fast_compile_options(llvm_opt_level: int = 0) -> dict[str, Any]:
    """Options for a program run a few times per calibration: those this XLA has.

    Args:
        llvm_opt_level: LLVM's optimisation level, 0–3. 0 compiles fastest; a program called
            hundreds of times (the diagnostics' batched Jacobians, once per LM iteration) is
            better off at 1, which runs it about 2.4× faster for about 0.3 s more compilation.
    """
    return _keep({**_CLASSIC_EMITTERS, _LLVM_OPT_LEVEL: llvm_opt_level})


def _built_at_first_call(fn: Callable, options: Callable[[], dict], jit: Callable, jit_kwargs):
    # JAX chooses its backend at the first computation, and the options are probed against
    # it, so the jitted function is built then, once, and reused afterwards.
    @functools.cache
    def jitted():
        return jit(fn, compiler_options=options(), **jit_kwargs)

    @functools.wraps(fn)
    def call(*args, **kwargs):
        return jitted()(*args, **kwargs)

    return call


def hot_loop(fn: Callable) -> Callable:
    """``eqx.filter_jit(fn)`` with :func:`loop_compiler_options`."""
    return _built_at_first_call(fn, loop_compiler_options, eqx.filter_jit, {})


def fast_compile(
    fn: Callable | None = None,
    *,
    jit: Callable = eqx.filter_jit,
    llvm_opt_level: int = 0,
    **jit_kwargs,
):
    """Decorator: ``jit(fn, **jit_kwargs)`` with :func:`fast_compile_options`."""
    if fn is None:
        return functools.partial(fast_compile, jit=jit, llvm_opt_level=llvm_opt_level, **jit_kwargs)
    return _built_at_first_call(
        fn, functools.partial(fast_compile_options, llvm_opt_level), jit, jit_kwargs
    )


def vectorise_small_loops() -> bool:
    """Let LLVM vectorise loops of 4 or more iterations in every program this process compiles.

    Adds :data:`SMALL_LOOPS_FLAG` to ``XLA_FLAGS``. It applies only if JAX has not yet started
    a backend (XLA reads its flags once, then) and ``XLA_FLAGS`` does not already set
    ``xla_backend_extra_options`` (the user's own choice is kept) nor name a flag file (XLA
    reads a value that does not start with ``--`` as a file name). Returns whether it applied.
    """
    flags = os.environ.get("XLA_FLAGS", "").strip()
    if flags and not flags.startswith("--"):
        return False
    if "xla_backend_extra_options" in flags or _backend_started():
        return False
    os.environ["XLA_FLAGS"] = f"{flags} {SMALL_LOOPS_FLAG}".strip()
    return True


def _backend_started() -> bool:
    try:
        from jax._src import xla_bridge
    except ImportError:  # a JAX that moved it: assume started, and change nothing
        return True
    started = getattr(xla_bridge, "backends_are_initialized", None)
    return True if started is None else bool(started())
