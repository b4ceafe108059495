"""Scenes: the hopper and the drum, built with trimesh, and the Scene they share with LIGGGHTS."""

from granular_pyg.scenes.drum import make_drum
from granular_pyg.scenes.hopper import make_hopper
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
    "make_drum",
    "make_hopper",
]
