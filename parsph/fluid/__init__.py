"""Implicit incompressible SPH (IISPH) fluid of the paper, section 4 (eqs. (28)-(41), (49)).

Modules (imported only by a scene with a fluid material, never at package import):

- :mod:`parsph.fluid.rheology`: strain rate (39), Bingham viscosity (40), eddy viscosity (41).
- :mod:`parsph.fluid.assembly`: numba kernels of the summation density (33) and the
  free-surface detection, the row order of the systems, the divergence (36) and the
  pressure gradient (37).
- :mod:`parsph.fluid.viscous`: the CSR block of the implicit viscous predictor (30)/(34)
  with wall ghost particles (Adami et al. 2012), and its explicit form.
- :mod:`parsph.fluid.ppe`: the CSR block of the pressure Poisson equation (32)/(35).
- :mod:`parsph.fluid.walls`: which wall layer a wall particle belongs to (its slip).
- :mod:`parsph.fluid.stage`: the :class:`~parsph.fluid.stage.IISPH` stage of the step.

See ``docs/iisph.md`` for the choices made where the paper is silent.
"""
