"""Where float32 still has a floor, and the warning a renderer gives there.

Every entry point works in a frame centred on the scene (see :class:`gridrt.FramePipeline`,
:func:`gridrt.build_grid`, :class:`gridrt.RayCaster`), so a scene's position in the world costs no
precision.  What remains is float32's relative precision *within* the scene: a coordinate of
magnitude M in the scene's frame is stored to within ``M * 2**-24``.  A scene whose triangles are
small against its own size (a city 1e7 across with millimetre detail) loses that detail: with a
median edge of E float32 steps of the scene's largest coordinate, measured on the Utah teapot
placed at one end of a scene (BENCHMARKS.md, "float32 floor"), hit distances are off by about
``2e-6 * 282 / E`` relatively and primary rays start to flip between hit and miss at E of about 3
steps.  :func:`detail_warning` flags scenes under :data:`FLOOR_STEPS` steps.
"""

import warnings

import numpy as np

#: Warn when the median triangle edge is under this many float32 steps (ulps) of the largest
#: coordinate in the scene's frame (hit distances are then off by more than about 1e-5).
FLOOR_STEPS = 32.0

#: Triangles sampled (evenly) for the median edge.
SAMPLE = 65536
#: ... by the one-shot builds (build_grid, RayCaster), which should cost little more than the grid
#: build itself: 8192 evenly spaced triangles (about 0.6 ms instead of 5 on a million triangles; the
#: median edge of a mesh is its own to within a few per cent at that sample, and the warning's
#: threshold is a factor, 32 steps)
ONE_SHOT_SAMPLE = 8192


class PrecisionWarning(UserWarning):
    """The scene's detail is below what float32 resolves at the scene's own size."""


def detail_steps(tris, sample=SAMPLE, big=None):
    """``(median edge, largest |coordinate|, edge in float32 steps)`` of (F,3,3) triangles in the
    frame they are rendered in; the median is over non-zero edges of up to ``sample`` triangles;
    ``big`` (the largest |coordinate|) is measured when not given."""
    t = np.asarray(tris)
    if len(t) == 0:
        return 0.0, 0.0, np.inf
    step = max(1, len(t) // sample)
    s = t[::step].astype(np.float64)
    e = np.linalg.norm(s[:, 1] - s[:, 0], axis=1)
    e = e[e > 0]
    if big is None:
        big = max(abs(float(t.min())), abs(float(t.max())))
    if len(e) == 0 or big == 0.0:
        return 0.0, big, np.inf
    edge = float(np.median(e))
    return edge, big, edge / (big * 2.0**-23)


def detail_warning(tris, what="the scene", sample=SAMPLE, big=None):
    """A one-line message when ``tris`` (in their frame) have detail float32 cannot resolve, else None."""
    edge, big, steps = detail_steps(tris, sample, big)
    if steps >= FLOOR_STEPS:
        return None
    return (f"{what} spans {2 * big:.3g} units in its frame but its median triangle edge is {edge:.3g}, only "
            f"{steps:.3g} float32 steps: detail this small is distorted (hit distances off by ~{2e-6 * 282 / steps:.0e} "
            f"relatively, pixels flip at edges below ~3 steps); render the small part on its own")


def warn_detail(tris, what="the scene", stacklevel=3, sample=SAMPLE, big=None):
    """Issue a :class:`PrecisionWarning` when :func:`detail_warning` has something to say; returns it."""
    msg = detail_warning(tris, what, sample, big)
    if msg is not None:
        warnings.warn(msg, PrecisionWarning, stacklevel=stacklevel)
    return msg
