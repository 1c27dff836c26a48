"""Timing rules shared by the benchmark scripts: interleaved repeats, medians, the machine.

Every comparison runs its contenders in turn, ``A B C A B C ...`` (the order rotated each
round so that none always runs right after the same one), at least five rounds, and
quotes the **median** of each contender's times; a ratio is the median of the ratios
of the same round, so that a slow moment of a shared machine slows both sides of it.
Never best-of.  :func:`machine` says where the numbers were taken, including the load
average before and after (other jobs on the machine slow everything).
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

#: Memory written between two timed calls when they should start cold (:func:`interleaved`):
#: far more than the L2 caches and the share of L3 a process gets on a shared machine.
COLD_BYTES = 128 << 20


@dataclass
class Timings:
    """Wall and CPU seconds per round of each contender (same rounds, same order)."""

    wall: dict[str, list[float]] = field(default_factory=dict)
    cpu: dict[str, list[float]] = field(default_factory=dict)
    results: dict[str, object] = field(default_factory=dict)

    def median(self, name: str, cpu: bool = False) -> float:
        return float(np.median((self.cpu if cpu else self.wall)[name]))

    def ratio(self, slow: str, fast: str) -> float:
        """Median over rounds of ``time(slow) / time(fast)`` (wall clock)."""
        a, b = np.asarray(self.wall[slow]), np.asarray(self.wall[fast])
        return float(np.median(a / b))

    def spread(self, name: str) -> float:
        """Relative spread (max - min) / median of a contender's wall times."""
        w = np.asarray(self.wall[name])
        return float((w.max() - w.min()) / np.median(w))


def interleaved(fns: Mapping[str, Callable[[], object]], rounds: int = 5,
                warmup: bool = True, cold: bool = False) -> Timings:
    """Run every function once per round, rotating the order; keep the last result.

    Args:
        fns: ``{name: zero-argument function}``.
        rounds: number of rounds (at least 5 for a quoted number).
        warmup: one untimed call of each first (imports, caches, JIT compilation).
        cold: before every call, untimed, write :data:`COLD_BYTES` of other memory, so
            that each contender starts with the CPU caches holding someone else's
            data whatever ran before it.  A call that follows a similar one (two
            variants of one tool) otherwise finds its arrays and code still cached
            and looks faster than it is; a calibration inside a user's program starts
            cold.
    """
    names = list(fns)
    out = Timings({k: [] for k in names}, {k: [] for k in names})
    if warmup:
        for k in names:
            fns[k]()
    junk = np.empty(COLD_BYTES // 8) if cold else None
    for i in range(rounds):
        order = names[i % len(names):] + names[: i % len(names)]
        for k in order:
            if junk is not None:
                junk.fill(float(i))
            c0, t0 = time.process_time(), time.perf_counter()
            res = fns[k]()
            out.wall[k].append(time.perf_counter() - t0)
            out.cpu[k].append(time.process_time() - c0)
            out.results[k] = res
    return out


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load_average() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "?"


def machine() -> str:
    """One line: CPU, cores, Python, NumPy and SciPy versions, BLAS threads, load."""
    import scipy

    threads = os.environ.get("OPENBLAS_NUM_THREADS", "default")
    return (f"{_cpu_model()}, {os.cpu_count()} cores; Python {platform.python_version()}, "
            f"NumPy {np.__version__}, SciPy {scipy.__version__}, BLAS threads {threads}; "
            f"load average (1, 5, 15 min) {load_average()}")
