"""Scenes: the hopper and the drum built with trimesh, scenes from STL files, and the Scene they
share with LIGGGHTS."""

from granular_pyg.scenes.containment import check_insertion_region, inside_walls
from granular_pyg.scenes.drum import make_drum
from granular_pyg.scenes.hopper import make_hopper
from granular_pyg.scenes.mesh_scene import make_mesh_scene
from granular_pyg.scenes.scene import Materials, ParticleSpec, Scene, Wall, WallMotion
from granular_pyg.scenes.wall_set import WallContacts, WallSet

__all__ = [
    "Materials",
    "ParticleSpec",
    "Scene",
    "Wall",
    "WallContacts",
    "WallMotion",
    "WallSet",
    "check_insertion_region",
    "inside_walls",
    "make_drum",
    "make_hopper",
    "make_mesh_scene",
]
