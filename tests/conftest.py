"""Test-session settings.

Single-threaded BLAS: the suite's matrices are small and many, so OpenBLAS's thread
start-up dominates and oversubscribes the 2-core CI machine (one calibration measured
26 s threaded vs 1.6 s single-threaded under load).  Must be set before NumPy loads.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
