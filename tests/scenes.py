"""Small scenes written by tests (TOML text, so tests exercise the real loader)."""

MOVING_2D = """
[scene]
name = "moving"
description = "two blocks passing through each other over a floor, periodic in x"

[domain]
dim = 2
particle_size = 0.05
lo = [0.0, -0.2]
hi = [2.0, 1.2]
periodic = [true, false]

[run]
end_time = 0.4
mode = "kinematic"
cfl = 0.5

[output]
every = 0.2
progress = false

[materials.sand]
model = "kinematic"
density = 1500.0

[[bodies]]
name = "left"
material = "sand"
shape = "box"
lo = [0.1, 0.0]
hi = [0.9, 0.5]
velocity = [2.0, 0.3]

[[bodies]]
name = "right"
material = "sand"
shape = "polygon"
vertices = [[1.0, 0.0], [1.9, 0.0], [1.9, 0.6], [1.2, 0.4]]
velocity = [-1.5, 0.0]

[[walls]]
name = "floor"
shape = "box"
lo = [0.0, -0.15]
hi = [2.0, 0.0]
"""

MOVING_3D = """
[scene]
name = "moving3d"

[domain]
dim = 3
particle_size = 0.1
lo = [0.0, 0.0, -0.4]
hi = [1.5, 1.0, 1.0]
periodic = [true, true, false]

[run]
end_time = 0.2
mode = "kinematic"
cfl = 0.5

[output]
every = 0.1
progress = false

[materials.rock]
model = "kinematic"
density = 2000.0

[[bodies]]
name = "slab"
material = "rock"
shape = "extruded_polygon"
vertices = [[0.0, 0.0], [1.2, 0.0], [0.0, 0.6]]
extent = [0.0, 1.0]
velocity = [1.0, -0.5, 0.0]

[[walls]]
name = "bed"
shape = "tank"
lo = [0.0, 0.0, 0.0]
hi = [1.5, 1.0, 0.9]
sides = ["bottom"]
"""


def write(tmpdir, text, name="scene.toml"):
    import os

    path = os.path.join(tmpdir, name)
    with open(path, "w") as fh:
        fh.write(text)
    return path
