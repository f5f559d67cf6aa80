"""Total-Lagrangian SPH solid: finite-strain elastoplasticity (paper section 3).

Constitutive models act on one material point and are plain numba functions, so they
can be tested alone and called from the particle loops:

- :mod:`parsph.core.tensor` (shared with the fluid) -- 3x3 helpers: symmetric
  eigen-decomposition (closed form with a Jacobi fall-back), tensor
  logarithm/exponential of symmetric positive-definite matrices, determinant, inverse.
- :mod:`parsph.solid.hencky` -- Hencky elasticity on the logarithmic strain and the
  elastic trial state, eqs. (15)-(16), (20)-(27).
- :mod:`parsph.solid.drucker_prager` -- Drucker-Prager return map with cohesion
  softening, Appendix A / Algorithm 1.
- :mod:`parsph.solid.cam_clay` -- modified Cam-Clay return map (Newton-Raphson),
  Appendix B / Algorithm 2.

The particle stage (:mod:`parsph.solid.stage`, class ``TLSPH``) is built on:

- :mod:`parsph.solid.kernels` -- numba pair loops over the reference CSR lists:
  corrected kernel gradient, eqs. (11)-(14), hourglass control.
- :mod:`parsph.solid.update` -- per-particle F, porosity (eq. (5)) and return maps.
- :mod:`parsph.solid.boundary` -- ``[[constraints]]`` and wall contact.
- :mod:`parsph.solid.triaxial` -- ``triaxial.csv`` of the drained triaxial scenes.

See ``docs/tlsph.md``.

Sign convention: tension positive for the Kirchhoff stress tau, the Cauchy stress sigma
and the nominal stress P everywhere outside the Drucker-Prager and Cam-Clay modules;
soil-mechanics quantities (p' compression positive, p_c > 0) live only inside those two
modules. See ``docs/constitutive.md``.

Importing this package imports nothing heavy; the submodules compile on first call
(``cache=True``).
"""
