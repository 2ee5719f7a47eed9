"""``gusts``: Ornstein-Uhlenbeck wind per component, ``dw = -w/T dt + sigma dB`` with stationary deviation half
the bound, projected back into the disk (Euler-Maruyama at the step length)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from stp_env.sim.fleet import agent_rows
from stp_env.sim.winds import register
from stp_env.sim.winds.base import WindModel, fleet_radii, uniform_in_fleet_disks


def project(w, radius):
    """``w`` ``(M, 2)`` scaled back into the disks of ``radius`` ``(M,)`` where it left them."""
    norm = jnp.linalg.norm(w, axis=-1, keepdims=True)
    return w * jnp.minimum(1.0, radius[:, None] / jnp.maximum(norm, 1e-12))


@register
@dataclasses.dataclass(frozen=True)
class Gusts(WindModel):
    """Attributes: time_constant: the correlation time ``T`` [s] (> 0)."""

    time_constant: float = 5.0
    name = "gusts"
    help = "Ornstein-Uhlenbeck with correlation time time_constant [s]"
    order = 2

    def __post_init__(self) -> None:
        t = self.time_constant
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t <= 0:
            raise ValueError(f"wind_model gusts: time_constant must be a finite number of seconds > 0; got {t!r}.")

    def initial(self, key, params):
        return uniform_in_fleet_disks(key, params)

    def draw(self, key, state, params):
        r = fleet_radii(params)
        tc = jnp.asarray(self.time_constant, jnp.float32)
        sigma = 0.5 * r[:, None] * jnp.sqrt(2.0 / tc)
        w = state.wind - state.wind / tc * params.episode.dt + sigma * jnp.sqrt(params.episode.dt) * jax.random.normal(
            key, state.wind.shape)
        w = project(w, r)
        return agent_rows(params, w), w
