"""The benchmarks' statistics: timings of repeated calls, medians with min and max, and the Pareto
front of cost against errors."""

import math
import time

import numpy as np


def timings(fn, runs, warmup=1):
    """(median, min, max) ms of ``runs`` calls of fn after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return stat(ts)


def stat(values):
    """(median, min, max) of a list of numbers (nan when empty)."""
    v = np.asarray(list(values), np.float64)
    if not len(v):
        return float("nan"), float("nan"), float("nan")
    return float(np.median(v)), float(v.min()), float(v.max())


def put_stat(row, key, values):
    """row[key], row[key_min], row[key_max] = median, min, max of values."""
    row[key], row[key + "_min"], row[key + "_max"] = stat(values)
    return row


def measured(row, key):
    """row[key], or None where the run did not measure it (absent, or NaN)."""
    m = row.get(key)
    return None if m is None or (isinstance(m, float) and math.isnan(m)) else m


def fmt_ms(row, key, digits=1):
    """'median [min-max]' for a put_stat key."""
    m = measured(row, key)
    if m is None:
        return "n/a"
    return f"{m:.{digits}f} [{row[key + '_min']:.{digits}f}-{row[key + '_max']:.{digits}f}]"


def pareto_front(points, rel_tol=0.03):
    """Indices of the non-dominated points.

    points: list of tuples (cost, err1, err2, ...), all to be minimised; NaN errors count as 0.
    Point a dominates b when a's cost is at most b's cost * (1 - rel_tol) or equal within it,
    every error of a is <= b's, and a is strictly better somewhere beyond the tolerance: costs
    within rel_tol of each other are a tie (timing noise), so neither dominates on cost alone.
    """
    P = [(float(p[0]), *[0.0 if (e is None or math.isnan(e)) else float(e) for e in p[1:]]) for p in points]
    front = []
    for i, b in enumerate(P):
        dominated = False
        for j, a in enumerate(P):
            if i == j:
                continue
            cost_better = a[0] < b[0] * (1.0 - rel_tol)
            cost_tie = not cost_better and a[0] <= b[0] * (1.0 + rel_tol)
            errs_le = all(x <= y for x, y in zip(a[1:], b[1:]))
            errs_lt = any(x < y for x, y in zip(a[1:], b[1:]))
            if errs_le and (cost_better or (cost_tie and errs_lt)):
                dominated = True
                break
        if not dominated:
            front.append(i)
    return front
