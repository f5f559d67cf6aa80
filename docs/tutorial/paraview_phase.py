"""A parsph run in ParaView, from the side: the particles at the last frame coloured by
phase (solid brown, fluid blue, wall grey) over the soil as it was at t = 0 (light).

    xvfb-run -a pvbatch docs/tutorial/paraview_phase.py RUN_DIR [OUT.png] [TIME]

OUT.png defaults to RUN_DIR/plots/paraview_phase.png, TIME (s) to the last frame. It runs
with ParaView's Python (pvbatch), not parsph's. The camera looks along z in 2D and along
y in 3D (x along the slope, z up), so a 3D slab is seen as its cross-section.
"""
import os
import sys

from paraview.simple import (ColorBy, CreateView, ForceTime, GetColorTransferFunction,
                             GetScalarBar, OpenDataFile, SaveScreenshot, Show, Text,
                             Threshold, Transform, UpdatePipeline)

run = sys.argv[1]
png = sys.argv[2] if len(sys.argv) > 2 else os.path.join(run, "plots", "paraview_phase.png")
xdmf = os.path.abspath(os.path.join(run, "particles.xdmf"))  # absolute: see docs/paraview.md
reader = OpenDataFile(xdmf)
times = list(reader.TimestepValues)
t = float(sys.argv[3]) if len(sys.argv) > 3 else times[-1]
UpdatePipeline(time=t, proxy=reader)
x0, x1, y0, y1, z0, z1 = reader.GetDataInformation().GetBounds()
flat = z1 - z0 < 1e-12  # a 2D run: every particle at z = 0
depth = 2 if flat else 1  # the axis the camera looks along

view = CreateView("RenderView")
view.ViewSize = [1600, 640]
view.ViewTime = t
view.UseColorPaletteForBackground = 0
view.Background = [1.0, 1.0, 1.0]
view.OrientationAxesVisibility = 0

# t = 0: the soil and fluid (phase < 2) in light tan, moved behind the last frame
start = ForceTime(Input=reader, ForcedTime=times[0], IgnorePipelineTime=1)
moving = Threshold(Input=start, Scalars=["POINTS", "phase"], LowerThreshold=0.0,
                   UpperThreshold=1.5)
behind = Transform(Input=moving)
behind.Transform.Translate = [0.0, 10.0, 0.0] if depth == 1 else [0.0, 0.0, -10.0]
before = Show(behind, view)
before.SetRepresentationType("Points")
before.PointSize = 7
ColorBy(before, None)
before.AmbientColor = before.DiffuseColor = [0.90, 0.80, 0.66]

now = Show(reader, view)  # the frame at t, by phase
now.SetRepresentationType("Points")
now.PointSize = 7
ColorBy(now, ("POINTS", "phase"))
phase = GetColorTransferFunction("phase")
phase.InterpretValuesAsCategories = 1
phase.Annotations = ["0", "solid", "1", "fluid", "2", "wall"]
phase.IndexedColors = [0.63, 0.32, 0.18, 0.20, 0.45, 0.80, 0.60, 0.60, 0.60]
now.SetScalarBarVisibility(view, True)
bar = GetScalarBar(phase, view)
bar.Title, bar.ComponentTitle = "phase", ""
bar.TitleColor = bar.LabelColor = [0.1, 0.1, 0.1]
bar.WindowLocation = "Any Location"  # across the top left, clear of the particles
bar.Orientation = "Horizontal"
bar.Position = [0.03, 0.72]
bar.ScalarBarLength = 0.3

label = Text(Text=f"t = {t:.2f} s by phase; light: the soil at t = {times[0]:.2f} s")
shown = Show(label, view)
shown.WindowLocation = "Upper Left Corner"
shown.Color = [0.1, 0.1, 0.1]
shown.FontSize = 20

# a parallel projection along the depth axis, the particles filling the picture
centre = [(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2]
up = (y0, y1) if flat else (z0, z1)
view.CameraFocalPoint = centre
if flat:
    view.InteractionMode = "2D"
    view.CameraPosition = [centre[0], centre[1], centre[2] + 100.0]
    view.CameraViewUp = [0.0, 1.0, 0.0]
else:
    view.CameraPosition = [centre[0], centre[1] - 100.0, centre[2]]
    view.CameraViewUp = [0.0, 0.0, 1.0]
view.CameraParallelProjection = 1
aspect = view.ViewSize[0] / view.ViewSize[1]
view.CameraParallelScale = 0.55 * max((x1 - x0) / aspect, up[1] - up[0])
os.makedirs(os.path.dirname(os.path.abspath(png)), exist_ok=True)
SaveScreenshot(png, view, ImageResolution=view.ViewSize)
print(f"{png}: t = {t:.6g} s")
