"""XLA compiler options for the optimisers' compiled loops on the CPU.

XLA's CPU backend hands some fused reductions to YNNPACK. For the objectives here (a few
hundred float64 operations per member, reduced over a handful of landmarks) that is slower
than XLA's own loops: it stores every intermediate array of the reduction and reads it back.
Turning it off made a DE generation at N = 10,000 about 1.4× faster on the 2-core CPU this
was tuned on (``benchmarks/de_throughput.py`` measures it). The options apply only to the
programs compiled with them, never to the user's own JAX code.
"""

from __future__ import annotations

import functools

import jax

_NO_YNN_FUSION = {"xla_cpu_experimental_ynn_fusion_type": ""}


@functools.cache
def loop_compiler_options() -> dict[str, str]:
    """The options, or none if this jaxlib's XLA does not know them (or is not on a CPU)."""
    if jax.default_backend() != "cpu":
        return {}
    try:
        jax.jit(lambda x: x + 1, compiler_options=_NO_YNN_FUSION).lower(1.0).compile()
    except Exception:  # an XLA without the option rejects it by name; run with its defaults
        return {}
    return dict(_NO_YNN_FUSION)
