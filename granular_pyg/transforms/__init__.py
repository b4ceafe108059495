"""PyG transforms: radius graph, virtual wall nodes (V1/V2/V3), random-walk noise, wall
presses."""

from granular_pyg.transforms.add_random_walk_noise import AddRandomWalkNoise
from granular_pyg.transforms.add_wall_nodes import NORMAL_VARIANTS, AddWallNodes
from granular_pyg.transforms.neighbour_list import NeighbourList
from granular_pyg.transforms.press_into_walls import PressIntoWalls
from granular_pyg.transforms.radius_graph import RadiusGraph, radius_graph

__all__ = [
    "NORMAL_VARIANTS",
    "AddRandomWalkNoise",
    "AddWallNodes",
    "NeighbourList",
    "PressIntoWalls",
    "RadiusGraph",
    "radius_graph",
]
