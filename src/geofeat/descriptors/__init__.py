"""Local descriptors computed on geodesic polar patches."""

from .geobit import GeoBit, generate_pattern, load_pattern

__all__ = ["GeoBit", "generate_pattern", "load_pattern"]
