"""BulkMotion: the one-step loss plus the error of each horizontal layer's mean acceleration."""

from __future__ import annotations

import torch
from torch_geometric.data import Batch

from granular_pyg.errors import InputError
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.training.objectives.base import Objective, masked_mse

__all__ = ["BulkMotion", "layer_mean_error"]


def layer_mean_error(
    pred: torch.Tensor,
    target: torch.Tensor,
    height: torch.Tensor,
    graph: torch.Tensor,
    layer: float,
) -> torch.Tensor:
    """MSE of the layer means: the particles of each graph are cut into horizontal layers
    ``layer`` (m) thick, counted up from the graph's lowest particle; within each layer the
    mean of ``pred [N, 3]`` is compared with the mean of ``target [N, 3]``, and the squared
    difference is averaged over the layers and the 3 components (one number, like
    ``mse_loss``). Rows with a NaN target are left out; a zero that keeps the graph if none is
    left. ``height [N]`` (m) is each particle's z (up, along gravity), ``graph [N]`` its graph's
    index. Only z and the graph decide the layers, so the value does not change when the scene
    is turned about gravity, mirrored or moved."""
    known = torch.isfinite(target).all(dim=1)
    if not bool(known.any()):
        return pred.sum() * 0.0
    pred, target = pred[known], target[known]
    height, graph = height[known].double(), graph[known]
    num_graphs = int(graph.max()) + 1
    lowest = torch.full((num_graphs,), float("inf"), dtype=height.dtype, device=height.device)
    lowest = lowest.scatter_reduce(0, graph, height, reduce="amin")
    level = torch.floor((height - lowest[graph]) / layer).long()
    cell = graph * (int(level.max()) + 1) + level
    _, cell = torch.unique(cell, return_inverse=True)
    num_cells = int(cell.max()) + 1
    count = torch.zeros(num_cells, dtype=pred.dtype, device=pred.device)
    count = count.index_add(0, cell, torch.ones_like(cell, dtype=pred.dtype))
    mean_diff = torch.zeros(num_cells, 3, dtype=pred.dtype, device=pred.device)
    mean_diff = mean_diff.index_add(0, cell, pred - target.to(pred.dtype)) / count[:, None]
    return (mean_diff**2).mean()


class BulkMotion(Objective):
    """GNS's one-step loss (:class:`~granular_pyg.training.objectives.OneStep`) plus ``weight``
    times :func:`layer_mean_error` of the same normalised accelerations.

    The per-particle MSE weighs a bias shared by a whole layer (a bed that descends too fast)
    no more than the particles' own scatter; the layer term weighs it ``1 + weight`` times as
    much, since a layer's mean error is the shared part.

    Args:
        layer: thickness of the horizontal layers (m).
        weight: factor of the layer term (0: the one-step loss).
        share: fraction of the batches that take it in a Mixture.
    """

    def __init__(self, layer: float = 0.01, weight: float = 10.0, share: float = 1.0) -> None:
        super().__init__(share)
        if not layer > 0:
            raise InputError(f"bulk_motion.layer: expected a thickness > 0 (m), got {layer!r}")
        if not weight >= 0:
            raise InputError(f"bulk_motion.weight: expected a factor >= 0, got {weight!r}")
        self.layer, self.weight = float(layer), float(weight)

    def loss(self, sim: LearnedSimulator, batch: Batch, generator: torch.Generator) -> torch.Tensor:
        pred = sim(batch)
        one_step = masked_mse(pred, batch.y, getattr(batch, "weight", None))
        if self.weight == 0:
            return one_step
        real = ~batch.is_wall
        graph = batch.batch[real] if getattr(batch, "batch", None) is not None else None
        if graph is None:
            graph = torch.zeros(int(real.sum()), dtype=torch.long, device=pred.device)
        height = batch.pos[real, 2]
        return one_step + self.weight * layer_mean_error(pred, batch.y, height, graph, self.layer)
