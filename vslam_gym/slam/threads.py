"""How many threads the BLAS library may use during an estimator step.

The estimator's dense algebra is small (3 x 3 pose blocks, vertex blocks of tens of
rows, a state of a few hundred variables). OpenBLAS's threads do not speed that up on an
idle machine and slow it down badly when another process holds the other cores (the
usual case: two environments in subprocesses, or a training process beside an
evaluation), because its threads wait for a busy core. Measured on the 2-core
development machine (``house``, 250 steps, two runs side by side): mean filter step 43-45
ms with the default two BLAS threads, 28-29 ms with one; alone, both 28 ms, with the
same poses to the last bit.

:func:`blas_threads` limits the BLAS library (numpy's and scipy's OpenBLAS, MKL, ...)
for the duration of a ``with`` block and restores the caller's setting afterwards, via
``threadpoolctl``.
"""

from __future__ import annotations

import contextlib
import numbers
from typing import Any

__all__ = ["blas_threads", "check_blas_threads"]

_controller: Any = None


def check_blas_threads(threads: object) -> int | None:
    """``threads`` as an int >= 1, or None.

    Raises:
        ValueError: neither None nor an integer >= 1.
    """
    if threads is None:
        return None
    if isinstance(threads, bool) or not isinstance(threads, numbers.Integral) or threads < 1:
        raise ValueError(f"blas_threads must be None or an integer >= 1, got {threads!r}")
    return int(threads)


def blas_threads(threads: int | None) -> contextlib.AbstractContextManager[Any]:
    """A context manager limiting the BLAS library to ``threads`` threads.

    The limit takes effect when this is called (use it in a ``with`` statement) and the
    previous setting comes back when the block ends.

    Args:
        threads: the limit (>= 1), or None to leave the BLAS library alone.

    Raises:
        ValueError: ``threads`` is neither None nor an integer >= 1.
    """
    global _controller
    if check_blas_threads(threads) is None:
        return contextlib.nullcontext()
    if _controller is None:
        # Created on first use, once numpy and scipy have loaded their BLAS libraries.
        from threadpoolctl import ThreadpoolController

        _controller = ThreadpoolController()
    return _controller.limit(limits=threads, user_api="blas")
