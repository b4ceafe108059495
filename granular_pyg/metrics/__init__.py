"""Metrics on Trajectories: pure functions on positions ``[T, N, 3]`` (m), NaN once gone.

- :mod:`~granular_pyg.metrics.emd`: the paper's EMD (W2^2 with POT, or W1) and EMD at 2^k.
- :mod:`~granular_pyg.metrics.flow`: position MSE, mixing entropy, flow profiles, discharge rate,
  leakage.
- :mod:`~granular_pyg.metrics.physics`: discharged fraction, centre of mass, angle of repose,
  crushed particles.
"""

from granular_pyg.metrics.emd import emd, emd_at_powers
from granular_pyg.metrics.flow import (
    discharge_rate,
    flow_profile,
    leaked_mask,
    leaked_particles,
    mixing_classes,
    mixing_entropy,
    mixing_entropy_curve,
    position_mse,
)
from granular_pyg.metrics.physics import (
    centre_of_mass,
    crushed_particles,
    discharged_fraction,
    dynamic_angle_of_repose,
)

__all__ = [
    "centre_of_mass",
    "crushed_particles",
    "discharge_rate",
    "discharged_fraction",
    "dynamic_angle_of_repose",
    "emd",
    "emd_at_powers",
    "flow_profile",
    "leaked_mask",
    "leaked_particles",
    "mixing_classes",
    "mixing_entropy",
    "mixing_entropy_curve",
    "position_mse",
]
