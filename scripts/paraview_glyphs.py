"""A parsph run in ParaView: particles by phase, arrows of velocity coloured by speed.

    xvfb-run -a pvbatch scripts/paraview_glyphs.py RUN_DIR OUT.png [TIME]

TIME (s) defaults to the last frame. Runs with ParaView's Python (pvbatch), not parsph's.
"""
import os
import sys

from paraview.simple import (ColorBy, CreateView, GetColorTransferFunction, GetScalarBar,
                             Glyph, OpenDataFile, SaveScreenshot, Show, UpdatePipeline)

run, png = sys.argv[1], sys.argv[2]
xdmf = os.path.abspath(os.path.join(run, "particles.xdmf") if os.path.isdir(run) else run)
reader = OpenDataFile(xdmf)  # ParaView's Xdmf3 reader: every field, v with 3 components
t = float(sys.argv[3]) if len(sys.argv) > 3 else reader.TimestepValues[-1]
UpdatePipeline(time=t, proxy=reader)
x0, x1, y0, y1, z0, z1 = reader.GetDataInformation().GetBounds()
vmax = reader.PointData["v"].GetRange(-1)[1] or 1.0  # largest |v| (m/s)

view = CreateView("RenderView")
view.ViewSize = [1600, 700]
view.ViewTime = t
view.UseColorPaletteForBackground = 0
view.Background = [1.0, 1.0, 1.0]
view.OrientationAxesVisibility = 0

points = Show(reader, view)  # every particle as a point, by phase
points.SetRepresentationType("Points")
points.PointSize = 3
ColorBy(points, ("POINTS", "phase"))
phase = GetColorTransferFunction("phase")
phase.InterpretValuesAsCategories = 1
phase.Annotations = ["0", "solid", "1", "fluid", "2", "wall"]
phase.IndexedColors = [0.63, 0.32, 0.18, 0.45, 0.68, 0.88, 0.78, 0.78, 0.78]

arrows = Glyph(Input=reader, GlyphType="Arrow")  # arrows of v, the fastest 6 % of the width
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
for lut, title in ((speed, "speed (m/s)"), (phase, "phase")):
    bar = GetScalarBar(lut, view)
    bar.Title, bar.ComponentTitle = title, ""
    bar.TitleColor = bar.LabelColor = [0.1, 0.1, 0.1]
points.SetScalarBarVisibility(view, True)

centre = [(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2]
view.CameraFocalPoint = centre
if z1 - z0 < 1e-12:  # 2D: look along -z, the particles filling the picture
    view.InteractionMode = "2D"
    view.CameraPosition = centre[:2] + [10.0]
    view.CameraViewUp = [0.0, 1.0, 0.0]
    view.CameraParallelProjection = 1
    aspect = view.ViewSize[0] / view.ViewSize[1]
    view.CameraParallelScale = 0.6 * max((x1 - x0) / aspect, y1 - y0)
else:  # 3D: from the front left, above, z up
    view.CameraPosition = [centre[0] - 1.0, centre[1] - 2.0, centre[2] + 1.2]
    view.CameraViewUp = [0.0, 0.0, 1.0]
    view.ResetCamera(False)
SaveScreenshot(png, view, ImageResolution=view.ViewSize)
print(f"{png}: t = {t:.6g} s, max |v| = {vmax:.3g} m/s")
