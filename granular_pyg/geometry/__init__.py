"""Geometry core: point-triangle distances, wall normals, the wall index (culling), segment
crossings, per-particle selection over pair lists and the scene's own horizontal frame."""

from granular_pyg.geometry.canonical_frame import canonical_frame
from granular_pyg.geometry.closest_point import (
    closest_point_on_segments,
    closest_point_on_triangles,
    triangle_regions,
)
from granular_pyg.geometry.crossing import SegmentCrossings, segment_triangle_crossings
from granular_pyg.geometry.grouping import argmin_per_group
from granular_pyg.geometry.horizontal_frames import (
    horizontal_frame,
    horizontally_isotropic,
    random_horizontal_frame,
)
from granular_pyg.geometry.normals import canonical_normals, orientation_key, triangle_normals
from granular_pyg.geometry.rigid import pose_about_axis, rotation_about_axis
from granular_pyg.geometry.surface_patches import PATCH_ANGLE_DEG, surface_patches
from granular_pyg.geometry.wall_index import WallIndex, WallPairs, dense_wall_pairs

__all__ = [
    "PATCH_ANGLE_DEG",
    "SegmentCrossings",
    "WallIndex",
    "WallPairs",
    "argmin_per_group",
    "canonical_frame",
    "canonical_normals",
    "closest_point_on_segments",
    "closest_point_on_triangles",
    "dense_wall_pairs",
    "horizontal_frame",
    "horizontally_isotropic",
    "orientation_key",
    "pose_about_axis",
    "random_horizontal_frame",
    "rotation_about_axis",
    "segment_triangle_crossings",
    "surface_patches",
    "triangle_normals",
    "triangle_regions",
]
