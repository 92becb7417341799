"""Progressive accumulation while the view is still: the viewer renders the same frame again with
its camera rays moved by a sub-pixel offset (Camera.jittered) and shows the running mean of the
samples, so edges converge to the pixel's box-filtered average (anti-aliasing) while nothing
moves.  The first sample is the centred frame, the exact image; the offsets that follow are the
(2, 3) Halton points of the pixel square, so any count of samples covers it evenly.  Anything that
changes the frame (time, camera, settings, size) starts again from the exact image.
"""

import numpy as np

#: samples averaged at most; the view is converged after this many (the viewer then idles)
MAX_SAMPLES = 64


def _radical_inverse(i, base):
    f, r = 1.0, 0.0
    while i > 0:
        f /= base
        r += f * (i % base)
        i //= base
    return r


def jitter(k):
    """Sub-pixel offset (jx, jy), each in [-0.5, 0.5), of sample ``k``: (0, 0) for the first
    (the exact frame), then the Halton (2, 3) points of the pixel square, shifted to its centre."""
    if k == 0:
        return (0.0, 0.0)
    return (_radical_inverse(k, 2) - 0.5, _radical_inverse(k, 3) - 0.5)


class Accumulator:
    """The running mean of the samples of one frame (``key``: what decides it)."""

    def __init__(self, max_samples=MAX_SAMPLES):
        self.max_samples = int(max_samples)
        self.key = None
        self.sum = None
        self.count = 0

    def reset(self, key=None):
        self.key, self.sum, self.count = key, None, 0

    def next_jitter(self, key):
        """The offset of the next sample of frame ``key`` (the first: (0, 0)), or None when its
        samples are complete; a new key starts again."""
        if key != self.key:
            self.reset(key)
        if self.count >= self.max_samples:
            return None
        return jitter(self.count)

    def add(self, key, image):
        """Add sample ``image`` ((H, W, 3|4) uint8) of frame ``key``; returns the mean so far as
        uint8 (the image itself for a first sample, or a sample of another frame)."""
        img = np.asarray(image)
        if key != self.key or self.sum is None or self.sum.shape != img.shape:
            self.reset(key)
            self.sum = img.astype(np.float32)
            self.count = 1
            return img
        self.sum += img
        self.count += 1
        return np.clip(np.rint(self.sum / self.count), 0, 255).astype(np.uint8)
