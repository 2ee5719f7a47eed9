"""A generic Hamilton-Jacobi level-set solver in JAX. It knows nothing about UAVs.

Modules: :mod:`~stp_env.hj.grid` (grids), :mod:`~stp_env.hj.sets` (input sets),
:mod:`~stp_env.hj.dynamics` (control-affine dynamics), :mod:`~stp_env.hj.derivatives` (upwind schemes),
:mod:`~stp_env.hj.settings` (schemes and presets), :mod:`~stp_env.hj.solver` (problems and time loop),
:mod:`~stp_env.hj.interpolation` (values, gradients and optimal inputs at arbitrary states),
:mod:`~stp_env.hj.shapes` (implicit surface functions).
"""

from stp_env.hj import interpolation, shapes
from stp_env.hj.dynamics import ControlAffineDynamics, FeedbackDynamics
from stp_env.hj.grid import Grid
from stp_env.hj.sets import Ball, Box, ProductSet
from stp_env.hj.settings import ACCURACY_PRESETS, SolverSettings
from stp_env.hj.solver import (
    ConvergedResult,
    ReachResult,
    cfl_time_step,
    solve,
    solve_until_converged,
    static_obstacle,
)

__all__ = [
    "ACCURACY_PRESETS",
    "Ball",
    "Box",
    "ControlAffineDynamics",
    "ConvergedResult",
    "FeedbackDynamics",
    "Grid",
    "ProductSet",
    "ReachResult",
    "SolverSettings",
    "cfl_time_step",
    "interpolation",
    "shapes",
    "solve",
    "solve_until_converged",
    "static_obstacle",
]
