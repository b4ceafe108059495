"""Metrics on Trajectories: pure functions (physics checks so far; EMD and more with issue 6)."""

from granular_pyg.metrics.physics import (
    centre_of_mass,
    discharged_fraction,
    dynamic_angle_of_repose,
)

__all__ = ["centre_of_mass", "discharged_fraction", "dynamic_angle_of_repose"]
