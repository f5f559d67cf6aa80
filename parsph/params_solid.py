"""Scene tables of the TLSPH solid: ``[solid]`` numerics and ``[[constraints]]``.

Plain validated dataclasses (no physics imported): owned by the solid stage.
"""
from __future__ import annotations

from dataclasses import dataclass

from parsph.schema import spec


@dataclass(frozen=True, kw_only=True)
class SolidNumerics:
    """``[solid]``: numerical parameters of the TLSPH solid (section 3)."""

    cfl: float = spec(0.5, doc="C_CFL^s of eq. (49): dt <= C d / c_p", gt=0.0, le=1.0)
