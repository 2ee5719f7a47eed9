"""Solver settings and accuracy presets."""

from __future__ import annotations

import dataclasses
import math
import numbers

from stp_env.hj.derivatives import BOUNDARIES, SCHEMES

INTEGRATORS = {"euler": 1, "rk2": 2, "rk3": 3}
DISSIPATIONS = ("local", "global")
TUBE_MODES = ("min_with_target", "freeze")

# level -> (upwind scheme, time integrator). hj_reachability uses the same pairs for "low", "medium" and
# "very_high"; its "high" is WENO3 + RK3, a scheme this package does not implement (WENO5 + RK2 instead).
ACCURACY_PRESETS = {
    "low": ("upwind1", "euler"),
    "medium": ("eno2", "rk2"),
    "high": ("weno5", "rk2"),
    "very_high": ("weno5", "rk3"),
}


@dataclasses.dataclass(frozen=True)
class SolverSettings:
    """Numerical settings of the level-set solver.

    Attributes:
        scheme: spatial upwind scheme: ``"upwind1"``, ``"eno2"`` or ``"weno5"``.
        integrator: TVD Runge-Kutta order: ``"euler"``, ``"rk2"`` or ``"rk3"``.
        dissipation: Lax-Friedrichs coefficients: ``"local"`` (``alpha_i(x)`` per node, from the dynamics'
            partial bounds) or ``"global"`` (its maximum over the grid). Use ``"local"`` for relative dynamics,
            whose coefficients grow with the distance from the origin (docs/numerics.md).
        cfl: CFL number; the time step is ``cfl / max_x sum_i alpha_i(x) / dx_i``.
        boundary: ghost-cell rule at non-periodic faces (see :mod:`stp_env.hj.derivatives`).
        tube_mode: how a tube ("reach at some time within the horizon") is enforced: ``"min_with_target"``
            (``V <- min(V, l)`` after every step, Mitchell's toolbox) or ``"freeze"`` (the value may only
            decrease: ``dV/ds <- min(dV/ds, 0)``, ``hj_reachability``'s ``backwards_reachable_tube``).
        weno_eps: epsilon of the WENO5 smoothness indicators.
        steps_per_chunk: time steps per dispatched device loop; the host only updates the progress bar between
            chunks, never inside one.
    """

    scheme: str = "weno5"
    integrator: str = "rk3"
    dissipation: str = "local"
    cfl: float = 0.75
    boundary: str = "extrapolate_away_from_zero"
    tube_mode: str = "min_with_target"
    weno_eps: float = 1e-6
    steps_per_chunk: int = 64

    def __post_init__(self) -> None:
        if self.scheme not in SCHEMES:
            raise ValueError(f"Unknown scheme {self.scheme!r}; allowed: {sorted(SCHEMES)}.")
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"Unknown integrator {self.integrator!r}; allowed: {sorted(INTEGRATORS)}.")
        if self.dissipation not in DISSIPATIONS:
            raise ValueError(f"Unknown dissipation {self.dissipation!r}; allowed: {DISSIPATIONS}.")
        if self.boundary not in BOUNDARIES:
            raise ValueError(f"Unknown boundary {self.boundary!r}; allowed: {BOUNDARIES}.")
        if self.tube_mode not in TUBE_MODES:
            raise ValueError(f"Unknown tube_mode {self.tube_mode!r}; allowed: {TUBE_MODES}.")
        if (isinstance(self.cfl, bool) or not isinstance(self.cfl, numbers.Real)
                or not (math.isfinite(self.cfl) and 0 < self.cfl <= 1)):
            raise ValueError(f"cfl must be a number in (0, 1]; got {self.cfl!r}.")
        object.__setattr__(self, "cfl", float(self.cfl))  # numpy scalars accepted, stored as float
        if not self.weno_eps > 0:
            raise ValueError(f"weno_eps must be positive; got {self.weno_eps!r}.")
        if int(self.steps_per_chunk) < 1:
            raise ValueError(f"steps_per_chunk must be >= 1; got {self.steps_per_chunk!r}.")

    @classmethod
    def with_accuracy(cls, level: str, **overrides) -> SolverSettings:
        """Preset: ``low`` (upwind1 + Euler), ``medium`` (ENO2 + RK2), ``high`` (WENO5 + RK2),
        ``very_high`` (WENO5 + RK3). Other fields may be overridden."""
        try:
            scheme, integrator = ACCURACY_PRESETS[level]
        except KeyError:
            raise ValueError(
                f"Unknown accuracy preset {level!r}; allowed: {list(ACCURACY_PRESETS)}."
            ) from None
        clash = sorted({"scheme", "integrator"} & set(overrides))
        if clash:
            raise ValueError(f"with_accuracy({level!r}) fixes scheme and integrator; got {clash} too. Use "
                             "SolverSettings(scheme=..., integrator=...) to choose them yourself.")
        return cls(scheme=scheme, integrator=integrator, **overrides)
