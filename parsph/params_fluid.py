"""Scene table of the IISPH fluid: ``[fluid]`` numerics.

A plain validated dataclass (no physics imported): owned by the fluid stage.
"""
from __future__ import annotations

from dataclasses import dataclass

from parsph.schema import spec


@dataclass(frozen=True, kw_only=True)
class FluidNumerics:
    """``[fluid]``: numerical parameters of the IISPH fluid (section 4)."""

    cfl: float = spec(0.1, doc="C_CFL^f of eq. (49): dt <= C d / v_max", gt=0.0, le=1.0)
