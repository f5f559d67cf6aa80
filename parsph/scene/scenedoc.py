"""The scene-key reference (``docs/scenes.md``), generated from the schema classes."""
from __future__ import annotations

from parsph.scene import schema
from parsph.scene.materials import MODELS
from parsph.scene.params_fluid import FluidNumerics
from parsph.scene.params_probes import Probe
from parsph.scene.params_solid import Constraint, Geostatic, SolidNumerics
from parsph.scene.loader import (Body, Domain, Gravity, Loading, Output, PhaseChange, Run, SceneInfo,
                          Study, Wall)

SECTIONS = (("[scene]", SceneInfo, "scene."), ("[domain]", Domain, "domain."),
            ("[run]", Run, "run."), ("[output]", Output, "output."), ("[study]", Study, "study."),
            ("[gravity]", Gravity, "gravity."), ("[loading]", Loading, "loading."),
            ("[solid]", SolidNumerics, "solid."), ("[geostatic]", Geostatic, "geostatic."),
            ("[fluid]", FluidNumerics, "fluid."),
            ("[phase_change]", PhaseChange, "phase_change."), ("[[bodies]]", Body, "bodies.N."),
            ("[[walls]]", Wall, "walls.N."), ("[[constraints]]", Constraint, "constraints.N."),
            ("[[probes]]", Probe, "probes.N."))

#: Lines printed under a section's heading, before its table.
NOTES = {
    "[[probes]]": [
        "Samples go to `DIR/probes.csv`, one tidy table with the columns",
        "`time,probe,point,field,value` (`point`: the station index, 0 for a point or a",
        "box; vectors per component, `v_x`), and the stations to `DIR/probes_points.csv`",
        "(`probe,type,measure,point,s,x,y[,z]`, `s` the distance along a line). Fields,",
        "measures and the parallel algorithm: `docs/probes.md`.", ""],
}


#: A whole small scene with the keys every scene has and the common optional ones.
EXAMPLE = """\
```toml
[scene]
name = "hydrostatic"
description = "water column at rest in a tank"

[domain]
dim = 2
particle_size = 0.02          # d (m); smoothing length h = 1.2 d
lo = [-0.1, -0.1]             # domain box (m): partitioning, particles leaving it stop the run
hi = [1.1, 1.3]
periodic = [false, false]     # optional

[run]
end_time = 1.0                # s
mode = "physics"              # or "kinematic" (move with initial velocity, no forces) or
                              # "geometry" (build, partition, write frame 0: a preview)

[output]
every = 0.1                   # s between frames

[materials.water]
model = "newtonian"
density = 1000.0

[[bodies]]                    # shapes: box, polygon (2D), extruded_polygon, heightmap, mesh (3D)
name = "water"
material = "water"
shape = "box"
lo = [0.0, 0.0]
hi = [1.0, 1.0]

[[walls]]                     # fixed ghost-particle layers, 3 layers (2h) unless `layers` says
name = "tank"
shape = "tank"                # layers around an inner box on the chosen sides; or box, polygon, mesh
lo = [0.0, 0.0]
hi = [1.0, 1.2]
sides = ["left", "right", "bottom"]
# friction = 0.0              # optional: a TLSPH solid's Coulomb coefficient on this wall
                              # (default solid.wall_friction): a rough floor, smooth sides
```
"""


#: What the tables below hold beyond the example, in words (after the example).
BEYOND = [
    "The keys every scene has: `domain.dim`, `domain.particle_size`, `run.end_time`,",
    "`output.every`. Built-in scenes are in `parsph/scenes/` (`parsph scenes`); a scene",
    "file is checked before anything is allocated: an unknown key, a wrong type, a NaN, a",
    "negative size or a missing file is refused with the file and the dotted key named.",
    "",
    "- **Bodies and walls**: boxes, polygons (2D), extruded polygons, height maps (3D: ESRI",
    "  ASCII grids, `ncols`, `nrows`, `xllcorner`, `yllcorner`, `cellsize`, then rows north",
    "  to south, or GeoTIFF DEMs in metres) and closed STL/OBJ meshes (`file`, `scale`,",
    "  `rotate`, `translate`; walls: layers inside or outside it). Paths are relative to",
    "  the scene file ([geometry.md](geometry.md)).",
    "- **Periodic axes** work in every scene, coupled ones included (`slope_failure_3d` is",
    "  periodic across the slope; [coupling.md](coupling.md)).",
    "- **Earthquake records**: `[loading] record = \"quake.csv\"`, a CSV of time and ground",
    "  accelerations with units in the header, enter both phases as a body acceleration",
    "  ([loading.md](loading.md)).",
    "- **Solids**: `[[constraints]]` (fixed particles, prescribed velocities, named initial",
    "  velocity profiles) and the `[solid]` table ([tlsph.md](tlsph.md)).",
    "- **Fluids**: the `[fluid]` table: PPE form, free-surface criterion, tolerances; the",
    "  viscous predictor is solved implicitly, as in the paper, unless ν Δt/h² is below",
    "  `explicit_viscous_number` (water); `preconditioner_reuse` solves share one AMG set-up",
    "  ([iisph.md](iisph.md)).",
    "- **Phase change**: the `[phase_change]` table (`eps_p_limit`, `fluid`, `min_support`,",
    "  `fluidise_failed`; [coupling.md](coupling.md)).",
    "- **Probes**: `[[probes]]` sample fields at points, along lines (deposit thickness with",
    "  `measure = \"depth\"`) and over boxes into `DIR/probes.csv` ([probes.md](probes.md)).",
    "",
    "Only the effects a scene calls for are built: the step is composed from its materials",
    "(`parsph/step/pipeline.py`), and a stage's module is imported only when needed, so a",
    "solid-only scene never imports petsc4py and a fluid-only scene never compiles the TLSPH",
    "kernels. Any key can be overridden: `--set domain.particle_size=0.01 --set",
    "bodies.0.velocity=[1,0]`.",
]


def _table(rows) -> list[str]:
    out = ["| key | default | meaning |", "|---|---|---|"]
    bar = "\\|"  # a literal | inside a Markdown table cell
    out += [f"| `{k}` | {d} | {doc.replace('|', bar)} |" for k, d, doc in rows]
    return out


def markdown() -> str:
    lines = ["# Scene keys", "",
             "Generated by `python -m parsph.scene.scenedoc` from the schema classes in",
             "`parsph/scene/loader.py` and `parsph/scene/materials.py` (a test keeps this page in step).",
             "Every key can be overridden with `--set KEY=VALUE` (the value is read as TOML;",
             "list entries as `bodies.0.lo`).", "",
             "## An annotated scene", "", EXAMPLE.rstrip("\n"), ""] + BEYOND + [""]
    for title, cls, prefix in SECTIONS:
        lines += [f"## {title}", ""] + NOTES.get(title, []) + _table(schema.describe(cls, prefix)) \
            + [""]
    lines += ["## [materials.NAME]", "", "`model` selects the parameters a material takes.", ""]
    for name, cls in MODELS.items():
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        rows = [r for r in schema.describe(cls, "materials.NAME.") if not r[0].endswith(".model")]
        lines += [f"### model = \"{name}\"", "", doc, ""] + _table(rows) + [""]
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown(), end="")
