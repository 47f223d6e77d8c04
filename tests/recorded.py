"""Whether this machine computes the recorded reference files' numbers bit for bit.

``tests/data/problem_regression.npz`` and ``tests/data/sampling_reference.npz`` were written
by CI's Python 3.11 run on one machine (``tests/data/reference_libraries.json``).  Their last
bits depend on more than the code:

* numpy and scipy (another LAPACK and BLAS build rounds a decomposition otherwise);
* the processor's vector instructions: numba compiles the kernel for the host, and OpenBLAS
  picks its kernels by it.  On a processor without AVX-512 (an AMD EPYC "znver3", AVX2
  only) the same libraries moved a short fit's end point and the sampler's chains in their
  last bits (CI, 2026-11-27), where the AVX-512 machine that recorded them matched exactly.

Elsewhere the tests hold the numbers to a tolerance instead (see each test).
"""

from __future__ import annotations

import json
from pathlib import Path

DATA = Path(__file__).resolve().parent / "data"


def host_vector_features() -> set[str]:
    """The AVX-512 and AVX features of the processor numba compiles for."""
    import llvmlite.binding as llvm

    return {k for k, on in llvm.get_host_cpu_features().items() if on and k.startswith("avx")}


def recording_machine() -> bool:
    """The recording's numpy and scipy, on a processor with the recording's vector
    instructions (``"cpu_features"``: each must be present)."""
    import numpy as np
    import scipy

    want = json.loads((DATA / "reference_libraries.json").read_text(encoding="utf-8"))
    if (np.__version__, scipy.__version__) != (want["numpy"], want["scipy"]):
        return False
    return set(want.get("cpu_features", ())) <= host_vector_features()
