"""Show a CPU image in a moderngl context: one RGBA8 texture and a fullscreen-triangle program
loaded from ``shaders/blit.vert`` and ``shaders/blit.frag``.  numpy row 0 (the image's top row)
is drawn at the top of the viewport.  The exposure (stops) scales the image's linear light (gamma
2.2) by 2^stops, clipped at white, as it is drawn; :func:`exposed` does the same on the CPU, for
the screenshots of what is shown."""

from pathlib import Path

import numpy as np

import gridrt


def _shader_dir():
    """The repository's shaders/ (source checkout, editable install), else the copy a wheel
    install puts inside the package, gridrt/shaders (pyproject package-data)."""
    here = Path(__file__).resolve().parents[2] / "shaders"
    if here.is_dir():
        return here
    return Path(gridrt.__file__).resolve().parent / "shaders"


#: folder holding blit.vert / blit.frag
SHADER_DIR = _shader_dir()


def load_shader_sources(shader_dir=SHADER_DIR):
    """(vertex source, fragment source) read from ``shader_dir``; FileNotFoundError names the
    missing file."""
    d = Path(shader_dir)
    out = []
    for name in ("blit.vert", "blit.frag"):
        p = d / name
        if not p.is_file():
            raise FileNotFoundError(f"shader {p} is missing (gridrt looks for its shaders in {d})")
        out.append(p.read_text())
    return tuple(out)


#: the display gamma the exposure works under (the image's values are light^(1 / GAMMA))
GAMMA = 2.2


def exposed(image, stops):
    """``image`` ((H, W, 3|4) uint8) as the blit shader shows it at exposure ``stops``: its colour
    channels ``(min((c / 255)^2.2 * 2^stops, 1))^(1 / 2.2)``, rounded to 8 bits (alpha kept); the
    image itself at 0 stops."""
    img = np.asarray(image)
    if stops == 0:
        return img
    c = img[..., :3].astype(np.float64) / 255.0
    c = np.minimum(c ** GAMMA * 2.0 ** float(stops), 1.0) ** (1.0 / GAMMA)
    out = img.copy()
    out[..., :3] = np.rint(c * 255.0).astype(np.uint8)
    return out


class Blitter:
    """Upload (H, W, 4) or (H, W, 3) uint8 images and draw them over the whole viewport.

    ``ctx`` is a moderngl.Context (window or standalone); call :meth:`release` before the
    context goes away.
    """

    def __init__(self, ctx, shader_dir=SHADER_DIR):
        import moderngl  # deferred: the OpenGL binding (moderngl) loads only where a window or context is made

        self._mgl = moderngl
        self.ctx = ctx
        vs, fs = load_shader_sources(shader_dir)
        self.program = ctx.program(vertex_shader=vs, fragment_shader=fs)
        if "u_image" in self.program:
            self.program["u_image"].value = 0
        self.exposure = 0.0
        self.vao = ctx.vertex_array(self.program, [])
        self.texture = None
        self.size = None  # (W, H) of the uploaded image

    def upload(self, image):
        """Copy ``image`` ((H, W, 4) or (H, W, 3) uint8) into the texture, recreating it when the
        size changes."""
        img = np.asarray(image)
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
            raise ValueError(f"image must be (H, W, 3|4) uint8, got {img.shape} {img.dtype}")
        if img.shape[2] == 3:
            img = np.concatenate([img, np.full(img.shape[:2] + (1,), 255, np.uint8)], axis=2)
        img = np.ascontiguousarray(img)
        h, w = img.shape[:2]
        if self.texture is None or self.size != (w, h):
            if self.texture is not None:
                self.texture.release()
            self.texture = self.ctx.texture((w, h), 4)
            self.texture.repeat_x = False
            self.texture.repeat_y = False
            self.size = (w, h)
        self.texture.write(img)

    def draw(self, viewport):
        """Draw the last uploaded image stretched over ``viewport`` = (x, y, width, height) of
        the currently bound framebuffer (nearest filtering when the sizes match exactly, else
        linear).  Does nothing before the first upload."""
        if self.texture is None:
            return
        mgl = self._mgl
        f = mgl.NEAREST if tuple(viewport[2:]) == self.size else mgl.LINEAR
        self.texture.filter = (f, f)
        if "u_exposure" in self.program:
            self.program["u_exposure"].value = float(self.exposure)
        self.ctx.viewport = tuple(int(v) for v in viewport)
        self.texture.use(0)
        self.vao.render(mgl.TRIANGLES, vertices=3)

    def release(self):
        for obj in (self.texture, self.vao, self.program):
            if obj is not None:
                obj.release()
        self.texture = self.vao = self.program = None
