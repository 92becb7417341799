"""Ray casting through the grid: watertight intersection, 3D DDA, tiled parallel rendering."""

from .render import BACKGROUND, Hits, Renderer, RenderResult, cast_rays, default_light, render

__all__ = ["BACKGROUND", "Hits", "Renderer", "RenderResult", "cast_rays", "default_light", "render"]
