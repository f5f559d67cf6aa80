"""Render a parsph run in ParaView: particles by phase, arrows of velocity coloured by speed.

    xvfb-run -a pvbatch scripts/paraview_glyphs.py out/demo out/demo/plots/paraview.png [TIME]

TIME (s) defaults to the last frame. Runs with ParaView's own Python (pvbatch), not with
parsph's; copy it and change what you like (docs/paraview.md).
"""
import os
import sys

from paraview.simple import (ColorBy, GetColorTransferFunction, Glyph, OpenDataFile,
                             ResetCamera, SaveScreenshot, Show, UpdatePipeline)
from paraview.simple import CreateView

run, png = sys.argv[1], sys.argv[2]
xdmf = os.path.abspath(os.path.join(run, "particles.xdmf") if os.path.isdir(run) else run)
reader = OpenDataFile(xdmf)  # Xdmf3ReaderS: every field, v a 3-component vector
times = list(reader.TimestepValues)
t = float(sys.argv[3]) if len(sys.argv) > 3 else times[-1]
UpdatePipeline(time=t, proxy=reader)
info = reader.GetDataInformation()
x0, x1, y0, y1, z0, z1 = info.GetBounds()
flat = z1 - z0 < 1e-12  # a 2D run: look along -z
vmax = reader.PointData["v"].GetRange(-1)[1] or 1.0

view = CreateView("RenderView")
view.ViewSize = [1600, 800]
view.ViewTime = t
view.Background = [1.0, 1.0, 1.0]
view.OrientationAxesVisibility = 0

# particles as points, by phase (0 solid, 1 fluid, 2 wall)
points = Show(reader, view)
points.SetRepresentationType("Points")
points.PointSize = 4
ColorBy(points, ("POINTS", "phase"))
phase = GetColorTransferFunction("phase")
phase.InterpretValuesAsCategories = 1
phase.Annotations = ["0", "solid", "1", "fluid", "2", "wall"]
phase.IndexedColors = [0.63, 0.32, 0.18, 0.12, 0.47, 0.71, 0.75, 0.75, 0.75]

# arrows of v, length |v| (the fastest 6 % of the domain's width), coloured by |v|
arrows = Glyph(Input=reader, GlyphType="Arrow")
arrows.OrientationArray = ["POINTS", "v"]
arrows.ScaleArray = ["POINTS", "v"]
arrows.ScaleFactor = 0.06 * (x1 - x0) / vmax
arrows.GlyphMode = "All Points"
shown = Show(arrows, view)
ColorBy(shown, ("POINTS", "v", "Magnitude"))
speed = GetColorTransferFunction("v")
speed.ApplyPreset("Viridis (matplotlib)", True)
speed.RescaleTransferFunction(0.0, vmax)
shown.SetScalarBarVisibility(view, True)
bar = speed.GetScalarBar(view) if hasattr(speed, "GetScalarBar") else None
if bar is not None:
    bar.Title, bar.ComponentTitle = "|v|", "(m/s)"
    bar.TitleColor = bar.LabelColor = [0.1, 0.1, 0.1]

if flat:
    view.InteractionMode = "2D"
    view.CameraPosition = [(x0 + x1) / 2, (y0 + y1) / 2, 10.0]
    view.CameraFocalPoint = [(x0 + x1) / 2, (y0 + y1) / 2, 0.0]
    view.CameraViewUp = [0.0, 1.0, 0.0]
ResetCamera(view)
SaveScreenshot(png, view, ImageResolution=view.ViewSize, TransparentBackground=0)
print(f"{png}: t = {t:.6g} s of {len(times)} frames, max |v| = {vmax:.3g} m/s")
