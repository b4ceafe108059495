"""PyG transforms: radius graph, virtual wall nodes (V1/V2/V3), random-walk noise."""

from granular_pyg.transforms.add_random_walk_noise import AddRandomWalkNoise
from granular_pyg.transforms.add_wall_nodes import NORMAL_VARIANTS, AddWallNodes
from granular_pyg.transforms.neighbour_list import NeighbourList
from granular_pyg.transforms.radius_graph import RadiusGraph, radius_graph

__all__ = [
    "NORMAL_VARIANTS",
    "AddRandomWalkNoise",
    "AddWallNodes",
    "NeighbourList",
    "RadiusGraph",
    "radius_graph",
]
