"""Metrics on Trajectories: pure functions on positions ``[T, N, 3]`` (m), NaN once gone.

- :mod:`~granular_pyg.metrics.emd`: the paper's EMD (W2^2 with POT, or W1), EMD at 2^k and the
  outlet point that stands in for the particles that left.
- :mod:`~granular_pyg.metrics.flow`: position MSE, mixing entropy, flow profiles, discharge rate.
- :mod:`~granular_pyg.metrics.leaks`: particles whose centre went through the Scene's walls.
- :mod:`~granular_pyg.metrics.physics`: discharged fraction, centre of mass, angle of repose,
  crushed particles, and the hopper's outlet height and drum's axis from a Scene.
"""

from granular_pyg.metrics.emd import emd, emd_at_powers, outlet_point
from granular_pyg.metrics.flow import (
    discharge_rate,
    flow_profile,
    mixing_classes,
    mixing_entropy,
    mixing_entropy_curve,
    position_mse,
)
from granular_pyg.metrics.leaks import leaked_mask, leaked_particles
from granular_pyg.metrics.physics import (
    across_drum_axis,
    centre_of_mass,
    centre_of_mass_swing,
    crushed_particles,
    discharged_fraction,
    drum_axis,
    dynamic_angle_of_repose,
    outlet_height,
)

__all__ = [
    "across_drum_axis",
    "centre_of_mass",
    "centre_of_mass_swing",
    "crushed_particles",
    "discharge_rate",
    "discharged_fraction",
    "drum_axis",
    "dynamic_angle_of_repose",
    "emd",
    "emd_at_powers",
    "flow_profile",
    "leaked_mask",
    "leaked_particles",
    "mixing_classes",
    "mixing_entropy",
    "mixing_entropy_curve",
    "outlet_height",
    "outlet_point",
    "position_mse",
]
