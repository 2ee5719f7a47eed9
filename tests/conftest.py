"""Shared test configuration: CPU-only JAX, float32 (no x64), matplotlib's Agg backend and a small, deterministic
hypothesis profile."""

from __future__ import annotations

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# Figures are written to files, never shown: the library selects no backend, the tests pick the file-only one.
os.environ.setdefault("MPLBACKEND", "Agg")

import jax
from hypothesis import HealthCheck, settings

jax.config.update("jax_platforms", "cpu")

# JIT compilation makes the first example of a property test slow; deadlines would only measure compilation.
settings.register_profile(
    "stp",
    deadline=None,
    max_examples=40,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile("thorough", deadline=None, max_examples=400)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "stp"))
