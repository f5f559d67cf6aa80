"""Maps of a 3D run over the terrain (``parsph maps``): rasters in the scene's x, y.

- :func:`~parsph.maps.compute.make_maps`: deposit thickness, erosion depth, maximum flow
  depth and speed, arrival time, the surfaces of the first and last frames as GeoTIFF
  (the DEM's CRS and transform) and PNG, and ``summary.json`` (volumes, run-out,
  travel angle, peak speed). Collective; definitions in docs/maps.md.
- :mod:`~parsph.maps.grid`: the grid and its rows per rank; :mod:`~parsph.maps.binning`:
  particles into cells; :mod:`~parsph.maps.summary`: the numbers; :mod:`~parsph.maps.render`:
  the pictures.
"""
