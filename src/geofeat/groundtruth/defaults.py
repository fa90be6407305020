"""Defaults of `geofeat groundtruth` (a light module: the CLI reads them without importing torch)."""

#: Control-point spacing, reference pixels (chosen by measurement, see BENCHMARKS.md).
DEFAULT_SPACING_PX = 16.0
#: The reference object mask reaches this far beyond the landmarks' convex hull, pixels.
DEFAULT_MARGIN_PX = 150.0
#: ... and keeps depths within this many metres of the landmarks' depth range.
DEFAULT_DEPTH_MARGIN_M = 0.15
