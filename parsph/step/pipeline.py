"""The step, composed from the scene: only the stages a scene calls for are built.

A stage is named in :data:`STAGES` by the module and class that implement it; the module
is imported only when a scene needs the stage. So a fluid-only scene never imports
``parsph.solid`` and a solid-only scene never imports ``solvers`` or petsc4py.
``parsph check`` prints :func:`plan`.

Stage protocol (duck-typed)::

    class MyStage:
        name = "my_stage"
        halo_fields = ("v",)           # fields read on halo rows (refreshed before step)
        def __init__(self, ctx): ...   # allocate fields with ctx.particles.add_field
        def max_dt(self, ctx) -> float # this stage's time-step limit (inf if none)
        def step(self, ctx, dt): ...   # advance / compute on ctx.particles[:n_owned]
        def stats(self) -> dict        # extra stats.csv columns of the last step
        def settle(self, ctx) -> dict  # optional: a fresh run's geostatic stage, before
                                       # t = 0 (parsph.solid.geostatic); None if none
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass


@dataclass(frozen=True)
class StageSpec:
    name: str
    module: str
    cls: str
    doc: str

    def load(self):
        """Import the implementing module (only now) and return the stage class."""
        return getattr(importlib.import_module(self.module), self.cls)


STAGES = {
    "kinematics": StageSpec("kinematics", "parsph.step.kinematics", "Kinematics",
                            "positions advance with the particle velocity, no force"),
    "density": StageSpec("density", "parsph.step.diagnostics", "DensityStage",
                         "SPH density summation, eq. (33) (diagnostic field rho)"),
    "iisph": StageSpec("iisph", "parsph.fluid.stage", "IISPH",
                       "implicit incompressible SPH fluid, eqs. (28)-(41)"),
    "tlsph": StageSpec("tlsph", "parsph.solid.stage", "TLSPH",
                       "total-Lagrangian elastoplastic solid, eqs. (2)-(27)"),
    "coupled": StageSpec("coupled", "parsph.coupling.stage", "Coupled",
                         "TLSPH solid + IISPH fluid coupled as FSI (eqs. (42)-(48)), "
                         "phase change (section 3.3)"),
}

#: Infrastructure every run has, in step order (printed by `parsph check`).
INFRASTRUCTURE = (
    ("migrate", "move particles to their owners; re-partition (RCB) when unbalanced"),
    ("halo", "refresh halo copies within the kernel support 2h"),
    ("neighbours", "cell-list neighbour search, CSR lists"),
)


def plan(scene) -> list[StageSpec]:
    """The physics stages of one step, in order, for this scene.

    A scene with both solid (TLSPH) and fluid (IISPH) materials gets the one
    ``coupled`` stage (section 5 and the phase change of section 3.3).
    """
    mode = scene.run.mode
    if mode in ("geometry", "kinematic"):
        names = ["kinematics", "density"] if mode == "kinematic" else ["density"]
        return [STAGES[n] for n in names]
    names = []
    for mat in scene.materials.values():
        for stage in mat.stages:
            if stage not in names:
                names.append(stage)
    if {"tlsph", "iisph"} <= set(names):
        return [STAGES["coupled"]]
    return [STAGES[n] for n in names]


def layout(stages) -> str:
    """How particles are distributed over the ranks for this set of stages.

    ``"reference"``: a TLSPH-only scene; ownership, halo and neighbour lists follow the
    reference positions X and are built once (section 3: the reference configuration is
    fixed). ``"current"``: anything with moving neighbourhoods; ownership follows the
    current positions x and the halo and neighbour lists are rebuilt every step.
    ``"mixed"``: a coupled scene; solid rows are owned by X (and keep their reference
    halo and lists inside the coupled stage), the other rows by x (docs/coupling.md).
    """
    names = {s.name for s in stages}
    if "coupled" in names:
        return "mixed"
    return "reference" if names == {"tlsph"} else "current"


def uses_petsc(stages) -> bool:
    """True if any stage solves the fluid's implicit systems on PETSc."""
    return any(s.name in ("iisph", "coupled") for s in stages)


def needs_petsc(stages, scene) -> bool:
    """True if the step solves any system on PETSc (the only case that imports solvers):
    the fluid's, or the non-local plastic strain of a regularised soil
    (:mod:`parsph.solid.regularise`)."""
    return uses_petsc(stages) or (
        any(s.name == "tlsph" for s in stages)
        and any(getattr(m, "regularised", False) for m in scene.materials.values()))
