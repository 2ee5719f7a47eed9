"""Build every reachability artifact of a scenario once, cached, with a summary of the numbers.

``build_reach_artifacts()`` computes (or loads) the avoid region, the robust-tracking bound, the relative buffer
regions for each ``k̄`` and the planner's disk radii, for the intruder paper's default scenario (``v in [0, 25]
m/s``, ``|omega| <= 2 rad/s`` for vehicles and intruder, wind 6 m/s (or 11), ``t_IAT = 10 s``, ``R_c = 100 m``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from stp_env.artifacts import ArtifactStore
from stp_env.dynamics import DubinsWind
from stp_env.reach.avoid import AvoidRegion, AvoidRegionConfig, compute_avoid_region
from stp_env.reach.buffer import (
    BufferConfig,
    BufferRadii,
    RelativeBuffer,
    buffer_radii,
    compute_relative_buffer,
    disk_conservatism,
)
from stp_env.reach.plots import footprint_area_ratio
from stp_env.reach.tracking import TrackingBound, TrackingConfig, compute_tracking_bound, default_tracking_bound


@dataclasses.dataclass(frozen=True)
class ReachArtifacts:
    avoid: AvoidRegion
    tracking: TrackingBound
    buffers: dict[int, RelativeBuffer]
    radii: dict[int, BufferRadii]

    def summary(self) -> dict:
        """The numbers the closing notes and BENCHMARKS.md quote."""
        avoid = self.avoid
        return {
            "wind_m_s": avoid.config.vehicle.wind,
            "collision_radius_m": avoid.config.collision_radius,
            "t_iat_s": avoid.config.t_iat,
            "detection_range_m": round(avoid.detection_range(), 2),
            "behind_extent_exact_m": avoid.config.behind_extent(),
            "avoid_disk_over_footprint_area": round(
                disk_conservatism(avoid.grid, avoid.values[0], avoid.detection_range()), 3),
            "tracking_bound_m": round(self.tracking.bound, 3),
            "tracking_converged": self.tracking.converged,
            "buffers": {
                str(k): {
                    "t_brd_s": round(self.radii[k].t_brd, 3),
                    "relative_buffer_radius_m": round(self.buffers[k].radius, 2),
                    "separation_radius_m": round(self.radii[k].separation, 2),
                    "buffer_radius_m": round(self.radii[k].buffer, 2),
                    "vb_disk_over_footprint_area": round(
                        disk_conservatism(self.buffers[k].config.grid, self.buffers[k].values,
                                          self.buffers[k].radius), 3),
                    "buffer_disk_over_grid_set_area": round(
                        footprint_area_ratio(avoid, self.tracking.bound, self.buffers[k], self.radii[k].buffer), 3),
                }
                for k in sorted(self.buffers)
            },
        }


def default_avoid_config(vehicle: DubinsWind, collision_radius: float = 100.0, t_iat: float = 10.0,
                         intruder: DubinsWind | None = None) -> AvoidRegionConfig:
    """The avoid-region parameters used throughout (so that every user shares one cached artifact): 61 slices
    (``tau`` every ``t_IAT / 60``: 1/6 s by default, fine enough for linear interpolation in ``tau``, and exact for
    ``t_BRD = t_IAT / k̄`` with ``k̄`` in 1..6) and a box of 1.45 times the set's exact extent behind the vehicle
    (the set reaches about 1.12 times that in front)."""
    intruder = vehicle if intruder is None else intruder
    closing = max(intruder.v_max + vehicle.wind + intruder.wind - vehicle.v_max, 0.0)
    behind = collision_radius + closing * t_iat
    return AvoidRegionConfig(vehicle=vehicle, intruder=intruder, collision_radius=collision_radius, t_iat=t_iat,
                             half_width=float(np.float32(1.45 * behind)), n_slices=61)


def build_reach_artifacts(wind: float = 6.0, kbars=(1, 2, 3, 4), *, avoid_config: AvoidRegionConfig | None = None,
                          tracking_config: TrackingConfig | None = None, buffer_grid=(61, 61, 60),
                          store: ArtifactStore | None = None, progress: bool = True) -> ReachArtifacts:
    """Computes or loads everything for one wind level. ``store=None`` uses the default cache directory."""
    store = ArtifactStore() if store is None else store
    vehicle = DubinsWind(v_min=0.0, v_max=25.0, omega_max=2.0, wind=wind)
    avoid_config = avoid_config or default_avoid_config(vehicle)
    avoid = compute_avoid_region(avoid_config, store=store, progress=progress)
    if tracking_config is None:
        tracking = default_tracking_bound(vehicle, store=store, progress=progress)
    else:
        tracking = compute_tracking_bound(tracking_config, store=store, progress=progress)
    buffers, radii = {}, {}
    d_a = avoid.detection_range()
    for kbar in kbars:
        cfg = BufferConfig(avoid=avoid_config, kbar=kbar, grid_points=buffer_grid)
        buffers[kbar] = compute_relative_buffer(cfg, avoid, store=store, progress=progress)
        radii[kbar] = buffer_radii(kbar, tracking.bound, d_a, buffers[kbar].radius, avoid_config.t_iat)
    return ReachArtifacts(avoid=avoid, tracking=tracking, buffers=buffers, radii=radii)
