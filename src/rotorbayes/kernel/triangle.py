"""The triangle of a tall, thin matrix's QR factorisation, on the kernel's threads (and
the difference quotients of a Jacobian's columns, the step before it).

Least squares on ``n`` residuals and ``k`` parameters needs, per iteration, only the
``(k + 1) x (k + 1)`` triangle ``T`` of ``[J | r] = Q T``: ``Tᵀ T`` holds ``Jᵀ J``,
``Jᵀ r`` and ``|r|²`` without the squared condition number of forming them.  The rows are
cut into blocks of a fixed size (not of the thread count: the same bits on 1 thread or
16), each block is triangularised by Householder reflections on its own thread, and the
blocks' triangles, stacked in order, are triangularised once more.  Compiled without
fast-math: the same operations in the same order give the same bits on any x86-64 or
aarch64 processor (reassociation would tie them to the vector width; it bought no speed,
320-360 us per 2048 x 14 block either way).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

#: The prange loops alone run in parallel: numba's other parallel transformations would
#: make the allocations and the row copies parallel loops of their own, each one more
#: kernel to compile.  With the copies written as loops, the two functions below compile
#: for 2.7 CPU s instead of 3.5 on 2 cores (the first fit compiles them); the same
#: operations, the same bits.
_PARALLEL = {
    "prange": True,
    "numpy": False,
    "setitem": False,
    "reduction": False,
    "comprehension": False,
    "inplace_binop": False,
    "stencil": False,
    "fusion": False,
}

#: Rows of a block: a 2048 x 14 block of doubles (230 kB) stays in a core's cache.
BLOCK_ROWS = 2048


@njit(cache=True, nogil=True)
def _householder(W, nb):  # pragma: no cover - compiled
    """Triangularise the first ``nb`` entries of the columns ``W[j]`` (``W`` is
    ``(c, rows)``: column j of the matrix is the row ``W[j]``) in place by Householder
    reflections; the triangle is left in ``W[c, j]`` for ``c >= j`` (row j of ``T``)."""
    nc = W.shape[0]
    for j in range(min(nc, nb)):
        col = W[j]
        # In units of the column's largest entry: no overflow or underflow of the squares
        # (a Jacobian's columns span many decades where a parameter barely acts).
        amax = 0.0
        for i in range(j, nb):
            amax = max(amax, abs(col[i]))
        if amax == 0.0:
            continue
        inv_a = 1.0 / amax
        sigma = 0.0
        for i in range(j + 1, nb):
            y = col[i] * inv_a
            sigma += y * y
        if sigma == 0.0:
            continue  # nothing below the diagonal: the column is in form already
        y0 = col[j] * inv_a
        mu = math.sqrt(y0 * y0 + sigma)
        v0 = y0 - mu if y0 <= 0.0 else -sigma / (y0 + mu)
        beta = 2.0 * v0 * v0 / (sigma + v0 * v0)
        inv = inv_a / v0
        for i in range(j + 1, nb):
            col[i] *= inv  # the reflector's tail (its head is 1)
        col[j] = amax * mu
        for c in range(j + 1, nc):
            other = W[c]
            s = other[j]
            for i in range(j + 1, nb):
                s += col[i] * other[i]
            s *= beta
            other[j] -= s
            for i in range(j + 1, nb):
                other[i] -= s * col[i]


@njit(cache=True, parallel=_PARALLEL, nogil=True)
def triangle(D, r, scale):  # pragma: no cover - compiled
    """``T`` (``(k + 1) x (k + 1)``, upper triangular) with ``Tᵀ T = Aᵀ A`` for
    ``A = [Dᵀ diag(scale) | r]``: ``D`` is ``(k, n)`` (row j is column j of the Jacobian,
    multiplied by ``scale[j]`` on the way in), ``r`` the ``n`` residuals.  Needs
    ``n >= 2 (k + 1)``."""
    k, n = D.shape
    nc = k + 1
    nblocks = max(1, n // BLOCK_ROWS)
    tops = np.zeros((nc, nblocks * nc))
    for b in prange(nblocks):
        a = b * n // nblocks
        e = (b + 1) * n // nblocks
        nb = e - a
        W = np.empty((nc, nb))
        for j in range(k):
            sj = scale[j]
            for i in range(nb):
                W[j, i] = D[j, a + i] * sj
        for i in range(nb):
            W[k, i] = r[a + i]
        _householder(W, nb)
        for j in range(nc):
            for c in range(j, nc):
                tops[c, b * nc + j] = W[c, j]
    _householder(tops, nblocks * nc)
    T = np.zeros((nc, nc))
    for j in range(nc):
        for c in range(j, nc):
            T[j, c] = tops[c, j]
    return T


@njit(cache=True, parallel=_PARALLEL, nogil=True)
def difference_quotients(D, base, steps):  # pragma: no cover - compiled
    """``D[j] = (D[j] - base) / steps[j]`` in place, in row blocks on the kernel's threads
    (the same operations, so the same bits, as NumPy's ``D -= base; D /= steps[:, None]``)."""
    k, n = D.shape
    nblocks = max(1, n // BLOCK_ROWS)
    for t in prange(k * nblocks):
        j = t // nblocks
        b = t - j * nblocks
        a = b * n // nblocks
        e = (b + 1) * n // nblocks
        sj = steps[j]
        for i in range(a, e):
            D[j, i] = (D[j, i] - base[i]) / sj


__all__ = ["BLOCK_ROWS", "difference_quotients", "triangle"]
