"""Ray casting through the grid: watertight intersection, single-ray 3D DDA and CGT packet
traversal, shading, tiled parallel rendering and batch casts."""

from .render import BACKGROUND, Hits, Renderer, RenderResult, cast_rays, default_light, render

__all__ = ["BACKGROUND", "Hits", "Renderer", "RenderResult", "cast_rays", "default_light", "render"]
