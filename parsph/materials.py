"""Material models a scene can name, with the parameters each one takes.

Each model is a frozen dataclass validated by :mod:`parsph.schema`; ``phase`` says which
phase its particles start in and ``stages`` which step stages the model needs (see
:mod:`parsph.pipeline`). Physics modules are not imported here: validating a scene
never compiles a kernel.
"""
from __future__ import annotations

from dataclasses import dataclass

from parsph import schema
from parsph.errors import SceneError
from parsph.schema import spec

PHASE_SOLID, PHASE_FLUID, PHASE_WALL = 0, 1, 2


@dataclass(frozen=True)
class Kinematic:
    """Particles that move with their initial velocity and feel no force.

    For previews of geometry, benchmarks of the distributed machinery and tests of
    migration and halos on a moving particle set.
    """

    model: str = spec(doc="material model")
    density: float = spec(doc="density (kg/m^3)", gt=0.0)

    phase = PHASE_FLUID
    stages = ("kinematics",)


@dataclass(frozen=True)
class Newtonian:
    """Incompressible Newtonian fluid (IISPH, paper section 4 with a constant viscosity)."""

    model: str = spec(doc="material model")
    density: float = spec(1000.0, doc="density rho_0 (kg/m^3)", gt=0.0)
    viscosity: float = spec(1.0e-6, doc="kinematic viscosity nu_f (m^2/s)", ge=0.0)
    eddy_viscosity: bool = spec(False, doc="add the Smagorinsky eddy viscosity, eq. (41)")

    phase = PHASE_FLUID
    stages = ("iisph",)


MODELS = {
    "kinematic": Kinematic,
    "newtonian": Newtonian,
}


def build_material(name: str, raw, source: str):
    """Validate one ``[materials.NAME]`` table into its model's dataclass."""
    path = f"materials.{name}"
    if not isinstance(raw, dict):
        raise SceneError(f"{source}: key '{path}': expected a table with a 'model' key")
    model = raw.get("model")
    if model not in MODELS:
        known = ", ".join(sorted(MODELS))
        raise SceneError(f"{source}: key '{path}.model': unknown material model {model!r}; "
                         f"available models: {known}")
    return schema.build(MODELS[model], raw, path, source)
