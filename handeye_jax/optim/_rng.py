"""Counter-based uniform random numbers for DE: SplitMix64 of (seed, stream, position).

JAX's own generators cost more per generation at N = 10,000 than the objective does on a
2-core CPU. SplitMix64 is a counter hash of a few integer operations that XLA fuses and
vectorises, about 15 times cheaper for the same draws (benchmarks/RESULTS.md, "Figures the
code's comments point to"), and it passes BigCrush. Each 64-bit word gives two uniforms of
32 bits: ample for a crossover test against CR, and for an index draw ``floor(u·m)`` whose
bias is below ``m / 2^32`` (2e-6 at m = 10^4). Needs 64-bit integers, so call it with x64 enabled.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray, UInt

_GOLDEN = 0x9E3779B97F4A7C15
_MIX1 = 0xBF58476D1CE4E5B9
_MIX2 = 0x94D049BB133111EB


def seed_from_key(key: PRNGKeyArray) -> UInt[Array, ""]:
    """A 64-bit seed drawn from a JAX PRNG key."""
    return jax.random.bits(key, (), jnp.uint64)


def splitmix64(x: UInt[Array, "*s"]) -> UInt[Array, "*s"]:
    """The SplitMix64 output function (Steele, Lea & Flood 2014) of a 64-bit counter."""
    u = jnp.uint64
    z = x * u(_GOLDEN)
    z = (z ^ (z >> u(30))) * u(_MIX1)
    z = (z ^ (z >> u(27))) * u(_MIX2)
    return z ^ (z >> u(31))


def uniforms(
    seed: UInt[Array, ""], stream: UInt[Array, ""] | int, shape: tuple[int, int]
) -> Float[Array, "n k"]:
    """Uniform numbers in [0, 1), 32 random bits each, of the given shape; distinct ``stream``
    values give independent, non-overlapping blocks (the counter is stream · n · ⌈k/2⌉ + position).
    """
    n, k = shape
    words = (k + 1) // 2
    row = jax.lax.broadcasted_iota(jnp.uint64, (n, words), 0)
    col = jax.lax.broadcasted_iota(jnp.uint64, (n, words), 1)
    counter = (
        jnp.asarray(stream, jnp.uint64) * jnp.uint64(n * words) + row * jnp.uint64(words) + col
    )
    bits = splitmix64(counter + jnp.uint64(1) + seed)
    halves = jnp.concatenate([bits >> jnp.uint64(32), bits & jnp.uint64(0xFFFFFFFF)], axis=1)
    return halves[:, :k].astype(jnp.int64).astype(jnp.float64) * (2.0**-32)
