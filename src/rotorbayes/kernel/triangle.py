"""The triangle of a tall, thin matrix's QR factorisation, on the kernel's threads (and
the difference quotients of a Jacobian's columns, the step before it).

Least squares on ``n`` residuals and ``k`` parameters needs, per iteration, only the
``(k + 1) x (k + 1)`` triangle ``T`` of ``[J | r] = Q T``: ``Tᵀ T`` holds ``Jᵀ J``,
``Jᵀ r`` and ``|r|²`` without the squared condition number of forming them.  The rows are
cut into blocks of a fixed size (not of the thread count: the same bits on 1 thread or
16), each block is triangularised by Householder reflections on its own thread, and the
blocks' triangles, stacked in order, are triangularised once more.  Compiled without
fast-math: the same operations in the same order give the same bits on any x86-64 or
aarch64 processor (fast-math's reassociation would tie them to the vector width).  The
sums run in eight partial sums in the code's own order instead (:func:`_dot`), so they
are as fast as a vectorised sum and still the same bits everywhere.
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


#: Row indices are unsigned in the loops down a column: a signed index makes numba check
#: each access for a negative (wraparound) index, which keeps LLVM from vectorising the
#: loop (a 14-column block: 76 ns a row signed, 44.5 unsigned, the same bits).
_U = np.uint64


@njit(cache=True, nogil=True, inline="always")
def _dot(a, b, lo, hi):  # pragma: no cover - compiled
    """``sum a[i] b[i]`` over ``lo <= i < hi`` in eight interleaved partial sums, added
    pairwise at the end.  The order is the code's, not the compiler's (no fast-math): the
    same bits on any vector width, and eight independent chains instead of one, so the
    sum runs at the processor's throughput rather than its addition latency."""
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
    i = _U(lo)
    h = _U(hi)
    while i + _U(8) <= h:
        s0 += a[i] * b[i]
        s1 += a[i + _U(1)] * b[i + _U(1)]
        s2 += a[i + _U(2)] * b[i + _U(2)]
        s3 += a[i + _U(3)] * b[i + _U(3)]
        s4 += a[i + _U(4)] * b[i + _U(4)]
        s5 += a[i + _U(5)] * b[i + _U(5)]
        s6 += a[i + _U(6)] * b[i + _U(6)]
        s7 += a[i + _U(7)] * b[i + _U(7)]
        i += _U(8)
    while i < h:
        s0 += a[i] * b[i]
        i += _U(1)
    return ((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))


@njit(cache=True, nogil=True, inline="always")
def _absmax(a, lo, hi):  # pragma: no cover - compiled
    """``max |a[i]|`` over ``lo <= i < hi`` in four interleaved maxima (exact in any
    order)."""
    m0 = m1 = m2 = m3 = 0.0
    i = _U(lo)
    h = _U(hi)
    while i + _U(4) <= h:
        m0 = max(m0, abs(a[i]))
        m1 = max(m1, abs(a[i + _U(1)]))
        m2 = max(m2, abs(a[i + _U(2)]))
        m3 = max(m3, abs(a[i + _U(3)]))
        i += _U(4)
    while i < h:
        m0 = max(m0, abs(a[i]))
        i += _U(1)
    return max(max(m0, m1), max(m2, m3))


@njit(cache=True, nogil=True)
def _householder(W, nb):  # pragma: no cover - compiled
    """Triangularise the first ``nb`` entries of the columns ``W[j]`` (``W`` is
    ``(c, rows)``: column j of the matrix is the row ``W[j]``) in place by Householder
    reflections; the triangle is left in ``W[c, j]`` for ``c >= j`` (row j of ``T``).

    A 2048 x 14 block takes 91 us on one core of the 2-core AMD EPYC (308 us with one
    summation chain and signed indices)."""
    nc = W.shape[0]
    end = _U(nb)
    for j in range(min(nc, nb)):
        col = W[j]
        # In units of the column's largest entry: no overflow or underflow of the squares
        # (a Jacobian's columns span many decades where a parameter barely acts).
        amax = _absmax(col, j, nb)
        if amax == 0.0:
            continue
        inv_a = 1.0 / amax
        for i in range(_U(j), end):
            col[i] *= inv_a
        sigma = _dot(col, col, j + 1, nb)
        if sigma == 0.0:  # nothing below the diagonal: the column is in form already
            for i in range(_U(j), end):
                col[i] *= amax
            continue
        y0 = col[j]
        mu = math.sqrt(y0 * y0 + sigma)
        v0 = y0 - mu if y0 <= 0.0 else -sigma / (y0 + mu)
        beta = 2.0 * v0 * v0 / (sigma + v0 * v0)
        inv = 1.0 / v0
        for i in range(_U(j + 1), end):
            col[i] *= inv  # the reflector's tail (its head is 1)
        col[j] = amax * mu
        for c in range(j + 1, nc):
            other = W[c]
            s = (other[j] + _dot(col, other, j + 1, nb)) * beta
            other[j] -= s
            for i in range(_U(j + 1), end):
                other[i] -= s * col[i]


@njit(cache=True, parallel=_PARALLEL, nogil=True)
def triangle(D, r, scale, base):  # pragma: no cover - compiled
    """``T`` (``(k + 1) x (k + 1)``, upper triangular) with ``Tᵀ T = Aᵀ A`` for
    ``A = [Dᵀ diag(scale) | r]``: ``D`` is ``(k, n)`` (row j is column j of the Jacobian,
    multiplied by ``scale[j]`` on the way in), ``r`` the ``n`` residuals.  With ``base``
    (``n`` values; empty: none) row j of ``D`` is a perturbed residual vector and column
    j of the Jacobian ``(D[j] - base) * scale[j]`` (the difference quotient formed on the
    way in: ``scale[j]`` then holds the column's scale over its step).  Needs
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
        ua = _U(a)
        for j in range(k):
            sj = scale[j]
            if base.shape[0] > 0:
                for i in range(_U(nb)):
                    W[j, i] = (D[j, ua + i] - base[ua + i]) * sj
            else:
                for i in range(_U(nb)):
                    W[j, i] = D[j, ua + i] * sj
        for i in range(_U(nb)):
            W[k, i] = r[ua + i]
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
