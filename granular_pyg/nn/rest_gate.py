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

The gate learns from its own loss, not only through the acceleration it multiplies (whose
gradient vanishes with the acceleration of a bed at rest): :func:`gate_labels` marks, from the
clean truth, the particles to shut (at rest in their history and their target, in windows
without noise) and those to open (their target moves); :func:`gate_hinge` pushes ``g`` below
``-1 - GATE_MARGIN`` for the first and to 0 (gate 1) for the second. The gate acts outside
training passes only (``LearnedSimulator._gate_acts``): in training the acceleration is the
network's own on every particle, so the acceleration's loss neither reaches the gate (in
windows with noise a particle at rest in the truth must be pushed back, and that pull held the
gate open) nor stops where the gate is shut (a release, which starts under a shut gate, would
never be learned).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from granular_pyg.nn.mlp import MLP

__all__ = [
    "GATE_GAIN",
    "GATE_MARGIN",
    "RestGate",
    "gate_hinge",
    "gate_labels",
    "gated",
]

#: How far below -1 a shut particle's logit is pushed, so that small input changes keep it shut.
GATE_MARGIN = 0.5

#: The logit is this times the MLP's output. Adam moves each weight by about the learning rate
#: per step, so at fine-tuning rates (2e-4) a unit gain took the logit 0.002 of the way to
#: shut in 300 steps; with this gain it crosses its range (0 to -1.5) in about a hundred.
GATE_GAIN = 20.0


class RestGate(nn.Module):
    """``[N, latent]`` node latents -> ``[N, 1]`` gate logits ``g`` (0 at initialisation):
    :data:`GATE_GAIN` times an MLP's output.

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
        return GATE_GAIN * self.mlp(latent)


def gated(acceleration: Tensor, logits: Tensor) -> Tensor:
    """``acceleration [N, 3]`` (m/s^2) times ``relu(1 + logits [N, 1])``: exactly zero where
    ``logits <= -1``, unchanged where ``logits == 0``."""
    return acceleration * torch.relu(1.0 + logits.to(acceleration.dtype))


def gate_labels(
    rest_history: Tensor, target_step: Tensor, step_at_rest: float, clean: bool
) -> Tensor:
    """``[N]`` labels for :func:`gate_hinge`: -1 shut, +1 open, 0 neither.

    Args:
        rest_history: ``[N]`` bool, the particle is at rest at every step of its clean history.
        target_step: ``[N, 3]`` (m) the clean target position minus the last clean position
            (NaN: a particle the truth has lost, left unlabelled).
        step_at_rest: the largest step (m) of a particle at rest.
        clean: the window's inputs are the truth without noise; only then is a particle at
            rest labelled shut (a noised input at rest in the truth is not at rest).
    """
    step = torch.linalg.vector_norm(target_step, dim=-1)
    labels = torch.zeros(step.shape, dtype=target_step.dtype)
    labels[step >= step_at_rest] = 1.0
    if clean:
        labels[rest_history & (step < step_at_rest)] = -1.0
    return labels


def gate_hinge(logits: Tensor, labels: Tensor) -> Tensor:
    """Mean over the ``N`` particles of ``relu(g + 1 + GATE_MARGIN)`` times ``-labels`` where
    ``labels [N]`` is negative (shut: the gate must stay closed under small changes) and ``|g|``
    times ``labels`` where it is positive (open: the gate 1, the acceleration passes whole);
    ``logits [N, 1]`` (``g``). Zero without labels."""
    g = logits[:, 0]
    shut = torch.relu(g + 1.0 + GATE_MARGIN) * (-labels).clamp(min=0)
    open_ = g.abs() * labels.clamp(min=0)
    return (shut + open_).mean()
