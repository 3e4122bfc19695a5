"""A batch of problems over JAX's devices: a mesh of this process's devices along one axis,
``problems``; a batch laid out on it with a ``NamedSharding`` (each device holds a block of
problems), and a compiled program run on every device's block at once.

Every device runs the same single-device program on its block (dispatched asynchronously,
so the devices work at the same time), and the outputs are joined back into one sharded
array. ``jax.shard_map`` would compile them as one program, but inside it optimistix's
Levenberg–Marquardt fails lineax's structure check on shard_map's varying-axis types
(JAX 0.10), and a block's numbers would then come from another program than a single run's.

A batch's leading axis is the problems'; its length must be a multiple of the mesh's size
(:func:`padded_size`). On a CPU, ``XLA_FLAGS=--xla_force_host_platform_device_count=K``
before JAX starts gives K host devices, each running on its own thread.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

#: The mesh axis a batch's problems are split along.
PROBLEMS = "problems"


def problem_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A one-axis mesh (``problems``) of ``devices`` (default: this process's devices)."""
    return Mesh(np.array(list(devices or jax.local_devices())), (PROBLEMS,))


def single_device_mesh() -> Mesh:
    """:func:`problem_mesh` of this process's first device: where one problem runs. (Not
    ``jax.devices()[0]``: under ``jax.distributed`` that is process 0's, which another
    process cannot run on.)"""
    return problem_mesh(jax.local_devices()[:1])


def padded_size(n: int, mesh: Mesh) -> int:
    """The smallest multiple of the mesh's size that holds ``n`` problems, each device's share
    rounded up to a power of two up to 64 and to a multiple of 64 above, so that batches of
    nearby sizes share their compiled programs."""
    devices = mesh.devices.size
    share = max(-(-n // devices), 1)
    share = 1 << (share - 1).bit_length() if share <= 64 else -(-share // 64) * 64
    return share * devices


class Blocks:
    """A pytree batch laid out on a mesh: one block of problems per device.

    Attributes:
        mesh: the devices.
        blocks: each device's block, a pytree of arrays on that device, in the mesh's order.
        n: how many of the batch's problems are real (the rest fill it, see :meth:`of`).
    """

    def __init__(self, mesh: Mesh, blocks: list[Any], n: int | None = None):
        self.mesh = mesh
        self.blocks = blocks
        self.n = n

    @classmethod
    def of(cls, tree: Any, mesh: Mesh, minimum: int = 1) -> Blocks:
        """``tree`` (array leaves with a leading axis of problems) sharded over the mesh along
        that axis; copies of its first problem fill it up to a multiple of the mesh's size
        and to at least ``minimum`` problems per device (:meth:`gather` leaves them out)."""
        sharding = NamedSharding(mesh, P(PROBLEMS))
        leaves, treedef = jax.tree.flatten(tree)
        if not leaves:  # nothing to place (a problem without data): each device gets it as is
            return cls(mesh, [tree] * mesh.devices.size)
        n = leaves[0].shape[0]
        devices = mesh.devices.size
        size = max(-(-n // devices), minimum) * devices
        if size != n:
            rows = np.concatenate([np.arange(n), np.zeros(size - n, int)])
            leaves = [np.asarray(x)[rows] for x in leaves]
        placed = jax.device_put([np.asarray(x) for x in leaves], sharding)  # one transfer
        per_device = {d: i for i, d in enumerate(mesh.devices.flat)}
        blocks: list[list[Any]] = [[None] * len(leaves) for _ in per_device]
        for j, x in enumerate(placed):
            for shard in x.addressable_shards:
                blocks[per_device[shard.device]][j] = shard.data
        return cls(mesh, [jax.tree.unflatten(treedef, b) for b in blocks], n)

    def gather(self) -> Any:
        """The batch as one host (NumPy) pytree, the blocks joined in order (the real
        problems only)."""
        return jax.tree.map(lambda *b: np.concatenate([np.asarray(x) for x in b])[: self.n],
                            *self.blocks)  # fmt: skip

    def sharded(self) -> Any:
        """The batch as global arrays sharded over the mesh (``NamedSharding``)."""
        sharding = NamedSharding(self.mesh, P(PROBLEMS))

        def join(*b):
            shape = (sum(x.shape[0] for x in b), *b[0].shape[1:])
            return jax.make_array_from_single_device_arrays(shape, sharding, list(b))

        return jax.tree.map(join, *self.blocks)


def per_device(program: Callable[..., Any], blocks: Blocks, *shared: Any) -> Blocks:
    """``program(block, *shared)`` on every device's block at once (each call dispatched
    before any is waited for): the outputs, one block per device.

    Args:
        program: a compiled (jitted) function of one block and of ``shared``; it returns
            arrays whose leading axis is the block's problems.
        blocks: the batch (see :meth:`Blocks.of`).
        shared: what every device gets whole (placed on each device by the call).
    """
    out = []
    for device, block in zip(blocks.mesh.devices.flat, blocks.blocks, strict=True):
        with jax.default_device(device):
            out.append(program(block, *shared))
    return Blocks(blocks.mesh, out, blocks.n)
