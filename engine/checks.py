"""Checks of plain values at gridrt's boundary: each returns the value in its plain Python type or
raises InputError naming it."""

import math

from .errors import InputError

#: the largest image width or height (RenderParams, Camera.rays)
MAX_IMAGE_SIDE = 16384


def check_finite(name, v):
    """``v`` as a finite float; InputError naming ``name`` for anything else (a bool too)."""
    if isinstance(v, bool) or type(v).__name__ == "bool_":
        raise InputError(f"{name} must be a number, got {v!r}")
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {v!r}") from None
    if not math.isfinite(f):
        raise InputError(f"{name} must be finite, got {v!r}")
    return f


def _positive_int(name, v, lo=1, hi=None):
    if isinstance(v, bool) or not isinstance(v, int):
        try:
            if int(v) != v:
                raise ValueError
            v = int(v)
        except (TypeError, ValueError, OverflowError):
            raise InputError(f"{name} must be an integer, got {v!r}") from None
    if v < lo or (hi is not None and v > hi):
        rng = f">= {lo}" if hi is None else f"between {lo} and {hi}"
        raise InputError(f"{name} must be {rng}, got {v}")
    return v
