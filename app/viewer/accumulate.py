"""Progressive accumulation while the view is still: the viewer renders the same frame again with
its camera rays moved by a sub-pixel offset (Camera.jittered) and shows the running mean of the
samples, so edges converge to the pixel's box-filtered average (anti-aliasing) while nothing
moves.  The first sample is the centred frame, the exact image; the offsets that follow are the
(2, 3) Halton points of the pixel square, so any count of samples covers it evenly.  Anything that
changes the frame (time, camera, settings, size) starts again from the exact image.

Where the render draws its lights (RenderParams.light_samples) each sample is a draw of its own
(light_seed = the sample's number), and the mean is taken of the colours before they are clamped
(Frame.hdr): that mean tends to the exact image, where a mean of clamped draws would not.
"""

import numpy as np

from gridrt.trace.material import radical_inverse

#: samples averaged at most; the view is converged after this many (the viewer then idles)
MAX_SAMPLES = 64


def jitter(k):
    """Sub-pixel offset (jx, jy), each in [-0.5, 0.5), of sample ``k``: (0, 0) for the first
    (the exact frame), then the Halton (2, 3) points of the pixel square, shifted to its centre."""
    if k == 0:
        return (0.0, 0.0)
    return (radical_inverse(k, 2) - 0.5, radical_inverse(k, 3) - 0.5)


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

    def add(self, key, image, hdr=None):
        """Add sample ``image`` ((H, W, 3|4) uint8) of frame ``key``; returns the mean so far as
        uint8, rounded half up (the image itself for a first sample, or a sample of another
        frame).  ``hdr`` ((H, W, 3) float, Frame.hdr) gives the hit pixels' colours before
        clamping (-1 for a miss): those pixels add 255 times them instead of the image's values."""
        img = np.asarray(image)
        v = img.astype(np.float64)
        if hdr is not None:
            hit = hdr[..., 0] >= 0.0
            v[..., :3][hit] = 255.0 * hdr[hit].astype(np.float64)
        if key != self.key or self.sum is None or self.sum.shape != img.shape:
            self.reset(key)
            self.sum = v
            self.count = 1
            return img
        self.sum += v
        self.count += 1
        # rounded as the renderer rounds a colour into the image (half up), so that draws which
        # agree show the exact image
        return np.clip(np.floor(self.sum / self.count + 0.5), 0, 255).astype(np.uint8)
