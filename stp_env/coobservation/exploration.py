"""The map-exploration cost of the co-observation paper's Example 1: Kalman-filter uncertainty of a slowly varying
field at points of interest, reduced by the robots' measurements.

Each point of interest ``x_j`` carries an independent scalar Kalman filter of the field value there (the paper
gives no model; these are our choices, see ``docs/coobservation.md``):

* prediction: ``P_j <- P_j + process_noise`` every step (the field drifts slowly: a random walk);
* update: a robot at ``q`` measures ``x_j`` with information ``h(|q - x_j|) / measurement_noise``, where ``h`` is
  a Gaussian radial basis function of width ``length_scale`` cut off smoothly at ``sensing_radius`` (the paper's
  "no further than 3 m"): ``P_j <- 1 / (1 / P_j + sum_i h(|q_i - x_j|) / measurement_noise)``.

The cost ``Phi(q)`` is a smooth maximum (log-sum-exp at ``temperature``) over the points of the variance after the
last step (the paper's "maximum uncertainty among map locations"), plus ``mean_weight`` times its mean, which keeps
a gradient on every point while the maximum is flat.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np


@dataclasses.dataclass(frozen=True, eq=False)
class ExplorationCost:
    """``Phi(q)`` of Example 1 for trajectories ``q`` ``(n_p, T + 1, 2)``; see the module docstring."""

    points: np.ndarray
    prior: float = 1.0
    process_noise: float = 0.02
    measurement_noise: float = 0.1
    length_scale: float = 1.2
    sensing_radius: float = 3.0
    temperature: float = 0.02
    mean_weight: float = 0.5

    def __post_init__(self):
        pts = np.asarray(self.points, np.float32)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0:
            raise ValueError(f"points must have shape (P >= 1, 2); got {pts.shape}.")
        for name in ("prior", "process_noise", "measurement_noise", "length_scale", "sensing_radius", "temperature"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a number > 0; got {v!r}.")
        object.__setattr__(self, "points", pts)

    @classmethod
    def grid(cls, lo, hi, spacing: float, **kwargs) -> ExplorationCost:
        """Points of interest on a regular grid over ``[lo, hi]`` with ``spacing`` (cell centres)."""
        xs = np.arange(lo[0] + spacing / 2, hi[0], spacing)
        ys = np.arange(lo[1] + spacing / 2, hi[1], spacing)
        pts = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
        return cls(points=pts, **kwargs)

    def quality(self, dist):
        """``h(d)``: Gaussian RBF times a smooth cutoff at ``sensing_radius``."""
        rbf = jnp.exp(-0.5 * (dist / self.length_scale) ** 2)
        cut = jax.nn.sigmoid((self.sensing_radius - dist) / (0.05 * self.sensing_radius))
        return rbf * cut

    def variances(self, q):
        """``(T + 1, P)``: every point's variance after each step's update."""
        pts = jnp.asarray(self.points)

        def step(p, q_t):
            p = p + self.process_noise
            d = jnp.sqrt(jnp.sum((q_t[:, None, :] - pts[None]) ** 2, -1) + 1e-12)
            info = jnp.sum(self.quality(d), axis=0) / self.measurement_noise
            p = 1.0 / (1.0 / p + info)
            return p, p

        p0 = jnp.full((pts.shape[0],), self.prior, jnp.float32) - self.process_noise
        _, ps = jax.lax.scan(step, p0, jnp.swapaxes(q, 0, 1))
        return ps

    def __call__(self, q):
        p = self.variances(q)[-1]
        smooth_max = self.temperature * jax.nn.logsumexp(p / self.temperature)
        return smooth_max + self.mean_weight * jnp.mean(p)

    def mean_variance(self, q) -> float:
        """The mean final variance over the points of interest."""
        return float(jnp.mean(self.variances(jnp.asarray(q, jnp.float32))[-1]))

    def max_variance(self, q) -> float:
        """The largest final variance (the quantity the paper minimises)."""
        return float(jnp.max(self.variances(jnp.asarray(q, jnp.float32))[-1]))
