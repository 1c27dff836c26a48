"""Working memory of repeated kinematic evaluations, owned by the caller.

The hot paths of a fit (the chain's sweep and point Jacobian, a measurement block's
system pieces, the compressed system's rows, the closed-form starts) need temporaries
of a few hundred kB to a few MB per piece of configurations.  An array that large is not
recycled by the C allocator: each fresh one is new memory from the operating system, and
touching it costs a page fault per 4 kB, as much as the arithmetic done in it at 10^3
measurements.  A :class:`ChainWorkspace` hands the memory of the last array of the same
name back instead.

It is explicit state, as Pinocchio's ``Data`` beside its ``Model``: the robot and the
measurement blocks are the model (immutable, shareable), and whoever evaluates them
repeatedly creates a workspace and passes it in (the stacked problem of a calibration
owns one and lends it to its blocks and the chain; a block's own evaluation makes one
per call; one-off calls of :meth:`kincal.robots.chain.Robot.fk` and friends get a fresh
one).  There is no module-level or thread-local pool.

Thread safety: a workspace is not shared between threads.  Two threads evaluating the
same robot or block each pass their own workspace (each calibration builds its own
stacked problem, so parallel folds and fleet or Dask workers never share one).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["ChainWorkspace", "WORKSPACE_BYTES"]

#: Bytes of working arrays a :class:`ChainWorkspace` keeps by default (64 MiB).
WORKSPACE_BYTES = 1 << 26


class ChainWorkspace:
    """Named float64 working arrays, grown on demand and reused from call to call.

    An array from :meth:`array` is valid until the next request of the same name from
    the same workspace: never hand one to a caller who keeps it.  At most ``max_bytes``
    are kept (beyond that a request gets fresh memory that is not kept); the arrays are
    bounded by the piece sizes, so memory stays ``O(parameters x piece)``.

    Not thread-safe: one workspace per thread of evaluation.

    Args:
        max_bytes: bytes of arrays kept at most (default :data:`WORKSPACE_BYTES`).
    """

    __slots__ = ("_arrays", "max_bytes")

    def __init__(self, max_bytes: int = WORKSPACE_BYTES) -> None:
        self.max_bytes = int(max_bytes)
        self._arrays: dict[str, Array] = {}

    def array(self, name: str, shape: tuple[int, ...]) -> Array:
        """An uninitialised C-contiguous float64 array of ``shape``: the memory of the
        last one named ``name`` when it is large enough, else new memory (kept for the
        next request when the workspace stays within ``max_bytes``)."""
        size = math.prod(shape)
        flat = self._arrays.get(name)
        if flat is None or flat.size < size:
            held = sum(a.nbytes for k, a in self._arrays.items() if k != name)
            flat = np.empty(size)
            if held + flat.nbytes > self.max_bytes:
                self._arrays.pop(name, None)
                return flat.reshape(shape)
            self._arrays[name] = flat
        return flat[:size].reshape(shape)

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays kept."""
        return sum(a.nbytes for a in self._arrays.values())

    def clear(self) -> None:
        """Release the arrays kept (the next requests allocate again)."""
        self._arrays.clear()

    def __repr__(self) -> str:
        return f"ChainWorkspace({len(self._arrays)} arrays, {self.nbytes} bytes)"
