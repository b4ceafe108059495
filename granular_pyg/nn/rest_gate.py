"""A learned gate that can stop a particle's acceleration exactly, as static friction does.

A bed at rest in the DEM is held by contact forces that balance gravity; a network that
predicts the acceleration must output zero there to within about 0.01 m/s^2 (0.1% of g) for a
bed to stay put for seconds, and stochastic training moves its output by more than that. A
gate makes rest an open set of states instead of one exact balance: the particle's acceleration
is multiplied by ``relu(1 + g)``, with ``g`` a scalar read from the processor's node latent.
Where ``g <= -1`` the acceleration is exactly zero, so a bed whose history is at rest keeps its
positions to the bit (semi-implicit Euler: zero velocity, zero acceleration), and small
changes of the inputs do not open the gate. The gate is a scalar, so an equivariant network
stays equivariant.

Its output layer starts at zero: ``g = 0``, gate 1, the network without the gate exactly, so a
trained model can learn the gate by fine-tuning.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from granular_pyg.nn.mlp import MLP

__all__ = ["RestGate", "gated"]


class RestGate(nn.Module):
    """``[N, latent]`` node latents -> ``[N, 1]`` gate logits ``g`` (0 at initialisation).

    Args:
        latent: width of the node latents.
        mlp_layers: hidden layers of the MLP.
    """

    def __init__(self, latent: int, mlp_layers: int = 2) -> None:
        super().__init__()
        self.mlp = MLP(latent, latent, 1, mlp_layers, layer_norm=False)
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)

    def forward(self, latent: Tensor) -> Tensor:
        return self.mlp(latent)


def gated(acceleration: Tensor, logits: Tensor) -> Tensor:
    """``acceleration [N, 3]`` (m/s^2) times ``relu(1 + logits [N, 1])``: exactly zero where
    ``logits <= -1``, unchanged where ``logits == 0``."""
    return acceleration * torch.relu(1.0 + logits.to(acceleration.dtype))
