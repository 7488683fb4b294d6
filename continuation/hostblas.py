"""How many threads the host's BLAS/LAPACK may use while a branch is walked.

The host linear algebra of continuation is small: LU solves of 402 (or 804) unknowns, products of
201- or 402-square blocks, and eigen-decompositions of 201-square parity blocks. LAPACK's Hessenberg QR
(``dgeev``) is not threaded at these sizes, and OpenBLAS's level-3 threading gains little there; but
its worker threads spin after every call, on the cores that Warp's CPU kernels, the tangent launches'
threads and the host copy threads need. On this project's 2-core CPU the paper's frequency branch took
51.3 s with OpenBLAS's default 2 threads and 24.7 s with 1 (``benchmarks/branch_profile.py``; the LU of
402 unknowns went from 15 to 1.7 ms per call, the Floquet products from 32 to 11 ms). One thread per BLAS
call also lets the even and odd parity blocks of the Floquet matrix be decomposed on two host threads
at once (``floquet.parity_blocks``), which two threads inside one OpenBLAS call cannot match.

``blas_threads(n)`` limits every loaded BLAS (numpy's and scipy's OpenBLAS, MKL, ...) to n threads
for the duration of a ``with`` block, through ``threadpoolctl``, and restores the previous limits
after. ``None`` leaves them alone. The limit is the process's, not the calling thread's: two branches
walked at once on two threads of one process share it, and the first to finish restores the old value.
"""

from __future__ import annotations

import contextlib

#: BLAS threads while a branch is walked, a breather is found or a scene runs (module docstring)
DEFAULT_BLAS_THREADS = 1


@contextlib.contextmanager
def blas_threads(threads: int | None = DEFAULT_BLAS_THREADS):
    """Limit the host BLAS to ``threads`` threads inside the block (None: no change)."""
    if threads is None:
        yield
        return
    if int(threads) < 1:
        raise ValueError(f"BLAS threads must be a whole number >= 1 or None, got {threads!r}")
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=int(threads), user_api="blas"):
        yield
