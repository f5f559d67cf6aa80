"""Material models a scene can name, with the parameters each one takes.

Each model is a frozen dataclass validated by :mod:`parsph.scene.schema`; ``phase`` says which
phase its particles start in and ``stages`` which step stages the model needs (see
:mod:`parsph.step.pipeline`). Physics modules are not imported here: validating a scene
never compiles a kernel.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from parsph.scene import schema
from parsph.errors import SceneError
from parsph.scene.schema import spec

from parsph.core.particles import PHASE_FLUID, PHASE_SOLID, PHASE_WALL  # noqa: F401 (the phases a model makes)


@dataclass(frozen=True, kw_only=True)
class Kinematic:
    """Particles that move with their initial velocity and feel no force.

    For previews of geometry, benchmarks of the distributed machinery and tests of
    migration and halos on a moving particle set.
    """

    model: str = spec(doc="material model")
    density: float = spec(doc="density (kg/m^3)", gt=0.0)

    phase = PHASE_FLUID
    stages = ("kinematics",)


@dataclass(frozen=True, kw_only=True)
class Newtonian:
    """Incompressible Newtonian fluid (IISPH, paper section 4 with a constant viscosity)."""

    model: str = spec(doc="material model")
    density: float = spec(1000.0, doc="density rho_0 (kg/m^3)", gt=0.0)
    viscosity: float = spec(1.0e-6, doc="kinematic viscosity nu_f (m^2/s)", ge=0.0)
    eddy_viscosity: bool = spec(False, doc="add the Smagorinsky eddy viscosity, eq. (41)")

    phase = PHASE_FLUID
    stages = ("iisph",)


@dataclass(frozen=True, kw_only=True)
class Bingham:
    """Bingham fluid for fluidised soil, eqs. (38)-(41): yield stress tau_y = c + p tan(phi)."""

    model: str = spec(doc="material model")
    density: float = spec(doc="density rho_0 (kg/m^3)", gt=0.0)
    viscosity: float = spec(1.0e-3, doc="initial viscosity nu_f0 (m^2/s)", ge=0.0)
    viscosity_max: float = spec(1.0e4, doc="viscosity cap nu_fMAX (m^2/s), eq. (40)", gt=0.0)
    cohesion: float = spec(0.0, doc="cohesion c (Pa) of the yield stress", ge=0.0)
    friction_angle: float = spec(0.0, doc="friction angle phi' (degrees)", ge=0.0, lt=90.0)
    eddy_viscosity: bool = spec(False, doc="add the Smagorinsky eddy viscosity, eq. (41)")

    phase = PHASE_FLUID
    stages = ("iisph",)


@dataclass(frozen=True, kw_only=True)
class _Solid:
    """Common parameters of the TLSPH soil models (section 3)."""

    model: str = spec(doc="material model")
    density: float = spec(doc="grain density rho_s (kg/m^3); rho_0 = (1 - n_0) rho_s", gt=0.0)
    porosity: float = spec(0.0, doc="initial porosity n_0 (-)", ge=0.0, lt=1.0)
    update_porosity: bool = spec(False, doc="update the porosity with eq. (5)")
    poisson_ratio: float = spec(doc="Poisson's ratio nu (-)", gt=-1.0, lt=0.5)

    phase = PHASE_SOLID
    stages = ("tlsph",)

    @property
    def reference_density(self) -> float:
        """rho_0 = (1 - n_0) rho_s (section 3.1)."""
        return (1.0 - self.porosity) * self.density


#: Default internal length of a softening soil without ``internal_length``, in particle
#: sizes of the scene as its file gives it (docs/regularisation.md).
DEFAULT_LENGTH_IN_D = 2.0
#: Smallest internal length a run accepts, in particle sizes (docs/regularisation.md).
MIN_RESOLVED = 1.0
#: The phase change's trigger window, in internal lengths: its radius
#: (:class:`parsph.solid.trigger.WindowTrigger`).
WINDOW_IN_ELL = 2.0


@dataclass(frozen=True, kw_only=True)
class _Softening:
    """The internal length of a soil that can soften (docs/regularisation.md)."""

    regularisation: str = spec("nonlocal", doc="nonlocal: softening and the phase-change "
                               "trigger see the internal length (docs/regularisation.md); "
                               "local: the paper's local rule", choices=("nonlocal", "local"))
    internal_length: Optional[float] = spec(None, doc="internal length l (m) of the non-local "
                                            "plastic strain; default 2 d of the scene file",
                                            gt=0.0)
    nonlocal_m: float = spec(2.0, doc="over-non-local factor m of the softening (-), "
                             "Vermeer & Brinkgreve (1994); 1 = softening on the average alone",
                             ge=1.0, le=10.0)

    def softens(self) -> bool:
        """Whether its softening sees the internal length (modified Cam-Clay's, on the dry
        side, stays local: docs/regularisation.md)."""
        return False

    def localises(self) -> bool:
        """Whether a shear band can form in it (softening, or a non-associative flow;
        modified Cam-Clay on the dry side)."""
        return True

    @property
    def regularised(self) -> bool:
        """Whether its softening and phase-change trigger see ``internal_length``: set
        when the scene loads (``nonlocal`` soils that soften, or that localise in a scene
        with a phase change, whose trigger then needs the length)."""
        return self.__dict__.get("_regularised", False)


@dataclass(frozen=True, kw_only=True)
class Hencky(_Solid):
    """Hencky hyperelastic solid, eqs. (15)-(16)."""

    young_modulus: float = spec(doc="Young's modulus E (Pa)", gt=0.0)


@dataclass(frozen=True, kw_only=True)
class DruckerPrager(_Softening, _Solid):
    """Hencky elasticity with non-associative Drucker-Prager plasticity, Appendix A."""

    young_modulus: float = spec(doc="Young's modulus E (Pa)", gt=0.0)
    friction_angle: float = spec(doc="friction angle phi' (degrees)", ge=0.0, lt=90.0)
    cohesion: float = spec(doc="initial cohesion c_0 (Pa)", ge=0.0)
    dilatancy_angle: float = spec(0.0, doc="dilatancy angle psi (degrees)", ge=0.0, lt=90.0)
    hardening: float = spec(0.0, doc="hardening modulus H (Pa), negative = softening")
    residual_cohesion: float = spec(0.0, doc="cohesion never softens below this (Pa)", ge=0.0)

    def softens(self) -> bool:
        """A softening cohesion (H < 0, Tables 2 and 3)."""
        return self.hardening < 0.0 and self.cohesion > self.residual_cohesion

    def localises(self) -> bool:
        """Softening, or a non-associative flow (psi < phi'), whose band forms even
        without softening (Rudnicki & Rice 1975)."""
        return self.softens() or self.dilatancy_angle < self.friction_angle


@dataclass(frozen=True, kw_only=True)
class CamClay(_Softening, _Solid):
    """Hencky-type elasticity with modified Cam-Clay plasticity, Appendix B."""

    kappa: float = spec(doc="gradient of the swelling line kappa (-)", gt=0.0)
    lam: float = spec(doc="gradient of the normal consolidation line lambda (-)", gt=0.0)
    critical_state_ratio: float = spec(1.0, doc="M, slope of the critical state line (-)",
                                       gt=0.0)
    preconsolidation: float = spec(doc="initial pre-consolidation pressure p_c (Pa)", gt=0.0)
    initial_pressure: float = spec(doc="initial isotropic effective stress p'_0 (Pa)", gt=0.0)


MODELS = {
    "kinematic": Kinematic,
    "newtonian": Newtonian,
    "bingham": Bingham,
    "hencky": Hencky,
    "drucker_prager": DruckerPrager,
    "cam_clay": CamClay,
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
    material = schema.build(MODELS[model], raw, path, source)
    if model == "cam_clay" and material.lam <= material.kappa:
        raise SceneError(f"{source}: key '{path}.lam': lambda ({material.lam}) must exceed kappa "
                         f"({material.kappa})")
    return material
