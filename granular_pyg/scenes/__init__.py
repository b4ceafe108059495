"""Scenes: the hopper and the drum, built with trimesh, and the Scene they share with LIGGGHTS."""

from granular_pyg.scenes.drum import make_drum
from granular_pyg.scenes.hopper import make_hopper
from granular_pyg.scenes.scene import Materials, ParticleSpec, Scene, Wall, WallMotion

__all__ = ["Materials", "ParticleSpec", "Scene", "Wall", "WallMotion", "make_drum", "make_hopper"]
