"""Uniform grids rebuilt from scratch every frame (Ize, Wald, Robertson, Parker, RT 2006)."""

from ..config import GridParams
from .build import GridBuilder, GridCapWarning, build_grid, grid_dims, make_spec
from .layout import INSERT_EPS, Grid, GridSpec
from .registry import BUILDERS, get_builder, names

__all__ = [
    "BUILDERS", "GridParams", "GridBuilder", "GridCapWarning", "Grid", "GridSpec", "INSERT_EPS",
    "build_grid", "get_builder", "grid_dims", "make_spec", "names",
]
