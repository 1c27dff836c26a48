"""Working arrays reused from call to call: one per name and thread.

The hot paths of a fit (the chain's sweep and point Jacobian, a measurement block's
system pieces, the compressed system's rows, the closed-form starts) need temporaries
of a few hundred kB to a few MB per piece of configurations.  An array that large is not
recycled by the C allocator: each fresh one is new memory from the operating system, and
touching it costs a page fault per 4 kB, as much as the arithmetic done in it at 10^3
measurements.  :func:`scratch` hands the memory of the last array of the same name back
instead.  It lives with the chain, the lowest layer that needs it; the measurement
models use the same pool.
"""

from __future__ import annotations

import math
import threading

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["scratch", "SCRATCH_BYTES"]

#: Bytes of working arrays :func:`scratch` keeps per thread.
SCRATCH_BYTES = 1 << 26

_SCRATCH = threading.local()


def scratch(name: str, shape: tuple[int, ...]) -> Array:
    """An uninitialised C-contiguous float64 array of ``shape``: the memory of the last
    one named ``name`` in this thread when it is large enough.

    An array from here is valid until the next request of the same name in the same
    thread: never hand one to a caller who keeps it.  At most :data:`SCRATCH_BYTES` are
    kept per thread (beyond that a request gets fresh memory); the arrays are bounded by
    the piece sizes, so memory stays ``O(parameters x piece)``.
    """
    size = math.prod(shape)
    pool: dict[str, Array] | None = getattr(_SCRATCH, "pool", None)
    if pool is None:
        pool = _SCRATCH.pool = {}
    flat = pool.get(name)
    if flat is None or flat.size < size:
        held = sum(a.nbytes for k, a in pool.items() if k != name)
        flat = np.empty(size)
        if held + flat.nbytes > SCRATCH_BYTES:
            pool.pop(name, None)
            return flat.reshape(shape)
        pool[name] = flat
    return flat[:size].reshape(shape)
