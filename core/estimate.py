"""Shared estimates made on a DSM before filtering: noise, terrain slope, block minima,
and the sampling of a large raster for them.

One copy of each estimate lives here, public, with a docstring that says what it measures
and on which surface. Filter modules call these when they derive their defaults (their
``resolve_*`` functions); where a method deliberately needs another statistic, its name
says so.
"""
