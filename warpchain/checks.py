"""Arguments checked at the public boundary: one message style, naming the argument (``real_number``,
``whole_number``). The lowest module of the package: it imports nothing of warpchain."""

from __future__ import annotations

import numpy as np


def real_number(name: str, value, *, positive: bool = False, nonnegative: bool = False) -> float:
    """Validate a real scalar at the public boundary: Python and numpy numbers and 0-d arrays are
    accepted; bools, complex numbers, strings, arrays with more than one value and non-finite values
    are refused with a message naming the argument."""
    if isinstance(value, (bool, np.bool_)) or isinstance(value, (str, bytes)):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    arr = np.asarray(value)
    if arr.ndim != 0 or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    out = float(arr)
    if not np.isfinite(out):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if positive and out <= 0:
        raise ValueError(f"{name} must be > 0, got {value!r}")
    if nonnegative and out < 0:
        raise ValueError(f"{name} must be >= 0, got {value!r}")
    return out


def whole_number(name: str, value, *, minimum: int | None = None) -> int:
    """Validate an integer (Python or numpy integer, or a 0-d integer array) at least ``minimum``."""
    arr = np.asarray(value) if not isinstance(value, (bool, np.bool_)) else np.asarray(1.5)
    if arr.ndim != 0 or not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    out = int(arr)
    if minimum is not None and out < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return out
