"""The papers' reachability sets around a single vehicle, each computed by the generic solver in
:mod:`stp_env.hj`. One module per concept."""

from stp_env.reach.avoid import AvoidRegion, AvoidRegionConfig, compute_avoid_region, plot_avoid_region

__all__ = ["AvoidRegion", "AvoidRegionConfig", "compute_avoid_region", "plot_avoid_region"]
