"""Scene table of the IISPH fluid: ``[fluid]`` numerics.

A plain validated dataclass (no physics imported): owned by the fluid stage
(:mod:`parsph.fluid.stage`). The paper (section 4) leaves the stabilisation ``alpha`` of
eq. (32), the free-surface criterion and the linear-solver tolerances open; the defaults
below are taken from the literature it cites and are discussed in ``docs/iisph.md``.
"""
from __future__ import annotations

from dataclasses import dataclass

from parsph.scene.schema import spec


@dataclass(frozen=True, kw_only=True)
class FluidNumerics:
    """``[fluid]``: numerical parameters of the IISPH fluid (section 4).

    Notes
    -----
    ``alpha`` is the stabilisation of the pressure Poisson equation (32) (Asai et al.
    2012, who recommend a small value, 0 <= alpha <= 1; alpha = 0 is the plain
    divergence-free projection, alpha = 1 the density-invariant one). The free surface
    is detected with the summation density (33) against a fraction ``beta`` of the rest
    density (Koshizuka & Oka 1996 use beta = 0.97 on the particle number density; with
    the cubic spline at h = 1.2 d, 0.9 flags exactly the outermost particle layer of
    a flat surface, see ``docs/iisph.md``).
    """

    cfl: float = spec(0.1, doc="C_CFL^f of eq. (49): dt <= C d / v_max", gt=0.0, le=1.0)
    alpha: float = spec(0.01, doc="stabilisation alpha of the PPE, eq. (32) (Asai et al. 2012), "
                        "0 <= alpha <= 1", ge=0.0, le=1.0)
    free_surface_beta: float = spec(0.9, doc="free surface: rho_i < beta rho_0 gets p = 0 "
                                    "(Koshizuka & Oka 1996 criterion on the density (33))",
                                    gt=0.0, lt=1.0)
    free_surface_gamma: float = spec(0.25, doc="free surface also where h |sum_j V_j grad W_ij| > "
                                     "gamma (incomplete support; 0.56 on a flat surface, 0.03 one "
                                     "layer below)", gt=0.0)
    surface_wall_contact: bool = spec(True, doc="a free-surface particle (p = 0, which the "
                                      "PPE does not hold off a boundary) closer than d to wall "
                                      "or soil particles loses its velocity towards them, and "
                                      "slides with Coulomb friction tan(phi') of a Bingham "
                                      "fluid (docs/iisph.md)")
    velocity_floor: float = spec(1.0, doc="v_max of eq. (49) is at least this times "
                                 "sqrt(|g| d) (a fluid at rest still gets a finite step)",
                                 ge=0.0)
    dt_max: float = spec(0.0, doc="upper bound of the fluid time step (s); 0 = none", ge=0.0)
    pressure_gradient: str = spec("hybrid", doc="corrector gradient: hybrid (eq. (37) inside, "
                                  "Bonet & Lok 1999 corrected difference on free-surface rows) | "
                                  "symmetric (eq. (37) everywhere) | corrected (everywhere)",
                                  choices=("hybrid", "symmetric", "corrected"))
    ppe_laplacian: str = spec("corrected", doc="PPE Laplacian: corrected (eq. (35) minus "
                              "2 e_i . grad p_i, exact for a linear pressure where the support "
                              "is truncated, docs/iisph.md) | paper (eq. (35) as printed)",
                              choices=("corrected", "paper"))
    density_correction: str = spec("auto", doc="density-error term of eq. (32): both (as "
                                   "printed) | compression (only rho > rho_0) | auto (both "
                                   "with a free surface, compression in a closed or periodic "
                                   "box, whose volume cannot adjust)",
                                   choices=("auto", "both", "compression"))
    numerical_viscosity: float = spec(0.0, doc="kappa: kappa h sqrt(|g| h) (m^2/s) is added "
                                      "to the viscosity of every fluid particle (vanishes as "
                                      "h^1.5; damps the free-surface noise of a fluid at rest, "
                                      "docs/iisph.md); 0 = off", ge=0.0)
    viscous_term: str = spec("paper", doc="viscous operator: paper (eq. (34)) | morris (Morris et "
                             "al. 1997; 1 % in shear on a lattice where eq. (34) is 20 % weak)",
                             choices=("paper", "morris"))
    viscous_solver: str = spec("auto", doc="viscous predictor (30): implicit (a PETSc solve "
                               "each step, as the paper) | explicit (the same operator at v^beta, "
                               "no matrix) | auto (explicit while the largest viscous number "
                               "nu dt / h^2 of the fluid, times the largest scale of a solid in "
                               "contact (its mass the fluid sees over its true mass, when over 1), "
                               "is below explicit_viscous_number, else implicit; docs/iisph.md)",
                               choices=("auto", "implicit", "explicit"))
    viscous_operator: str = spec("matrix_free", doc="an implicit viscous solve's operator: "
                                 "matrix_free (the pairs of eq. (34) applied in GMRES, BoomerAMG "
                                 "on a scalar matrix of the same pairs: a ninth of the entries, "
                                 "docs/solvers.md) | assembled (the dim x dim blocks in a PETSc "
                                 "matrix, block BoomerAMG on them)",
                                 choices=("matrix_free", "assembled"))
    viscous_preconditioner_reach: float = spec(
        1.5, doc="matrix_free: pairs closer than this many particle sizes d enter the scalar "
        "matrix BoomerAMG is set up on (the operator keeps every pair, so the solution is "
        "the same); 1.5 keeps ~18 of ~57 neighbours in 3D: the viscous solve 2.3x faster "
        "at the same iterations and its hierarchy a third (docs/solvers.md); 0 = every pair",
        ge=0.0)
    ppe_preconditioner_drop: float = spec(
        0.1, doc="BoomerAMG of the PPE is set up on a sparser copy of its matrix: each row "
        "keeps the entries of at least this share of its largest off-diagonal one, the others "
        "added to its diagonal (the operator keeps every entry, so the solution is the same); "
        "0.1: about an iteration more and the PPE solve twice as fast in 3D (docs/solvers.md); "
        "0 = the whole matrix", ge=0.0, lt=1.0)
    splitting: str = spec("projection_first", doc="order of an implicit step's two solves: "
                          "projection_first (the PPE on v + dt g, then the viscous solve on "
                          "the projected velocity with the new pressure in the yield stress "
                          "(40); a highly viscous fluid's weight goes to the pressure) | paper "
                          "(the viscous predictor (30) first, eqs. (30)-(31); a Bingham deposit "
                          "creeps, docs/coupling.md)", choices=("projection_first", "paper"))
    explicit_viscous_number: float = spec(0.01, doc="auto: largest nu dt / h^2 solved "
                                          "explicitly (water at the CFL step: ~1e-3; a Bingham "
                                          "fluid: 1e2 and more; forward Euler is stable below "
                                          "~0.1); an implicit solve below it (fluid.viscous_"
                                          "solver = implicit, a light solid) is preconditioned "
                                          "by Jacobi, not BoomerAMG (docs/solvers.md)",
                                          gt=0.0, le=0.1)
    clamp_negative_pressure: bool = spec(True, doc="set negative PPE pressures to 0 before the "
                                         "corrector (Koshizuka & Oka 1996)")
    ppe_rtol: float = spec(1e-8, doc="relative tolerance of the pressure solve (ppe_ksp_rtol)",
                           gt=0.0, lt=1.0)
    ppe_density_error: float = spec(0.0, doc="the pressure solve also stops once the RMS "
                                    "density error its residual leaves is at most this, "
                                    "relative to rho0 (IISPH's eta, e.g. 1e-4 = 0.01 %; "
                                    "SPlisHSPlasH stops at a mean of 0.01 %); 0: ppe_rtol "
                                    "alone (docs/iisph.md)", ge=0.0, lt=1.0)
    visc_rtol: float = spec(1e-8, doc="relative tolerance of the viscous predictor solve "
                            "(visc_ksp_rtol)", gt=0.0, lt=1.0)
    max_it: int = spec(500, doc="maximum Krylov iterations of either solve", gt=0)
    preconditioner_reuse: int = spec(4, doc="PPE solves that share one AMG set-up while the rows "
                                     "are the same particles (1 = a fresh set-up every step); "
                                     "a fresh one when the iterations grow by half, and "
                                     "particles change rank only every this many steps unless "
                                     "they stray d/2 beyond their sub-domain "
                                     "(docs/iisph.md)", ge=1, le=50)
    smagorinsky: float = spec(0.2, doc="Smagorinsky constant C_s of eq. (41)", ge=0.0)
    les_width: float = spec(0.1, doc="filter width Delta of eq. (41) in units of h "
                            "(the paper: Delta = 0.1 h)", gt=0.0)
