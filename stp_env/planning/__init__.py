"""Sequential trajectory planning (STP): single-vehicle reach-avoid planning and the sequential planner."""
