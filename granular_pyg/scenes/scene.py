"""The Scene: the single description of a set-up, shared by LIGGGHTS and the learned simulator.

A :class:`Scene` holds named triangle-mesh walls, each with a motion (static or a rigid rotation)
and an optional removal time, the particles to insert, gravity, the outflow rule, the materials
and the DEM/recording times. ``granular_pyg.dem`` renders it into a LIGGGHTS input script;
``granular_pyg.simulator`` rolls the learned model out over the same Scene, so the two can never
disagree about geometry.

Time convention: ``t = 0`` is the first recorded frame. LIGGGHTS first fills and settles the
particles for ``settle_time`` seconds (not recorded) with every wall at its ``t = 0`` pose;
wall motions and removals are given in recorded time.

Outflow rule: a particle whose centre drops below ``outflow_z`` leaves the scene for good. In
LIGGGHTS the simulation box ends at ``outflow_z`` (``boundary f f f`` with lost atoms ignored),
so the particle is deleted there; the learned simulator applies the same test, and a Trajectory
stores NaN for a particle from the first frame it is gone.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from granular_pyg.errors import InputError

__all__ = ["Materials", "ParticleSpec", "Scene", "Wall", "WallMotion"]


@dataclass(frozen=True)
class WallMotion:
    """Rigid motion of a wall: static, or rotation about ``axis`` through ``origin``.

    Attributes:
        kind: ``"static"`` or ``"rotation"``.
        axis: rotation axis (unit vector after normalisation), right-handed.
        origin: a point on the axis (m).
        omega: angular velocity (rad/s), the sign follows the right-hand rule about ``axis``.
        start_time: recorded time (s) at which the rotation starts.
    """

    kind: str = "static"
    axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    omega: float = 0.0
    start_time: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("static", "rotation"):
            raise InputError(f"motion.kind: expected 'static' or 'rotation', got {self.kind!r}")
        if self.kind == "rotation" and not np.any(np.asarray(self.axis, float)):
            raise InputError("motion.axis: a rotation needs a non-zero axis")

    def angle(self, t: float) -> float:
        """Rotation angle (rad) at recorded time ``t`` (s)."""
        if self.kind == "static":
            return 0.0
        return self.omega * max(0.0, t - self.start_time)

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Pose at recorded time ``t`` (s): ``(rotation [3, 3], translation [3])`` with
        ``x_world = rotation @ x_mesh + translation``."""
        angle = self.angle(t)
        if angle == 0.0:
            return np.eye(3), np.zeros(3)
        axis = np.asarray(self.axis, float)
        x, y, z = axis / np.linalg.norm(axis)
        k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
        rot = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)
        origin = np.asarray(self.origin, float)
        return rot, origin - rot @ origin


@dataclass
class Wall:
    """A named triangle mesh with a motion and an optional removal time.

    Attributes:
        name: identifier (letters, digits, underscore), used for STL files and LIGGGHTS fixes.
        vertices: ``[V, 3]`` float64 (m), in the mesh frame (the pose at ``t = 0`` is identity).
        faces: ``[F, 3]`` int64 vertex indices.
        motion: how the wall moves.
        removal_time: recorded time (s) at which the wall disappears (the hopper's lid), or None.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    motion: WallMotion = field(default_factory=WallMotion)
    removal_time: float | None = None

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise InputError(f"wall name {self.name!r}: use letters, digits and underscores")
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise InputError(
                f"wall {self.name}: vertices must be [V, 3], got {self.vertices.shape}"
            )
        if self.faces.ndim != 2 or self.faces.shape[1] != 3 or len(self.faces) == 0:
            raise InputError(f"wall {self.name}: faces must be [F>0, 3], got {self.faces.shape}")
        if self.faces.min() < 0 or self.faces.max() >= len(self.vertices):
            raise InputError(
                f"wall {self.name}: face indices out of range [0, {len(self.vertices)})"
            )
        if not np.isfinite(self.vertices).all():
            raise InputError(f"wall {self.name}: vertices contain NaN or Inf")

    @property
    def triangles(self) -> np.ndarray:
        """``[F, 3, 3]`` vertex positions per face in the mesh frame (m)."""
        return self.vertices[self.faces]

    def present(self, t: float) -> bool:
        """Whether the wall exists at recorded time ``t`` (s)."""
        return self.removal_time is None or t < self.removal_time

    def vertices_at(self, t: float) -> np.ndarray:
        """``[V, 3]`` world-frame vertices at recorded time ``t`` (s)."""
        rot, shift = self.motion.pose(t)
        return self.vertices @ rot.T + shift


@dataclass(frozen=True)
class Materials:
    """Contact model parameters (Hertz with tangential history), SI units."""

    youngs_modulus: float = 5.0e6  # Pa
    poisson_ratio: float = 0.3
    restitution: float = 0.6
    friction: float = 0.5
    rolling_friction: float = 0.0  # 0 disables LIGGGHTS's rolling_friction cdt
    density: float = 2500.0  # kg/m^3


@dataclass(frozen=True)
class ParticleSpec:
    """Particles to insert: ``count`` spheres of ``radius`` (m) in the box ``fill_lo..fill_hi``."""

    count: int
    radius: float
    fill_lo: tuple[float, float, float]
    fill_hi: tuple[float, float, float]


@dataclass
class Scene:
    """A complete set-up; see the module docstring for the time and outflow conventions.

    Attributes:
        name: scene kind, e.g. ``"hopper"`` or ``"drum"``.
        walls: the meshes.
        particles: what to insert.
        materials: contact parameters.
        gravity: ``[3]`` acceleration (m/s^2).
        domain_lo, domain_hi: simulation box (m); must contain every wall at every pose.
        outflow_z: particles whose centre falls below this height (m) leave; None for a closed
            scene.
        dem_dt: DEM time step (s).
        settle_time: fill-and-settle time before recording (s).
        duration: recorded time (s).
        frame_dt: time between recorded frames (s), a multiple of ``dem_dt``.
        params: the scene parameters it was built from (alpha, opening, omega, ...).
    """

    name: str
    walls: list[Wall]
    particles: ParticleSpec
    materials: Materials = field(default_factory=Materials)
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    domain_lo: tuple[float, float, float] = (-1.0, -1.0, -1.0)
    domain_hi: tuple[float, float, float] = (1.0, 1.0, 1.0)
    outflow_z: float | None = None
    dem_dt: float = 2.0e-5
    settle_time: float = 0.5
    duration: float = 1.0
    frame_dt: float = 2.5e-3
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        names = [w.name for w in self.walls]
        if len(set(names)) != len(names):
            raise InputError(f"scene {self.name}: wall names must be unique, got {names}")
        ratio = self.frame_dt / self.dem_dt
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise InputError(
                f"scene {self.name}: frame_dt ({self.frame_dt}) must be a multiple of "
                f"dem_dt ({self.dem_dt})"
            )
        if self.outflow_z is not None and abs(self.outflow_z - self.domain_lo[2]) > 1e-12:
            raise InputError(
                f"scene {self.name}: outflow_z ({self.outflow_z}) must equal domain_lo z "
                f"({self.domain_lo[2]}): particles leave through the box's floor"
            )

    @property
    def num_frames(self) -> int:
        """Recorded frames, including the one at ``t = 0``."""
        return round(self.duration / self.frame_dt) + 1

    def wall(self, name: str) -> Wall:
        for wall in self.walls:
            if wall.name == name:
                return wall
        raise KeyError(
            f"scene {self.name} has no wall {name!r}; walls: {[w.name for w in self.walls]}"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description (wall arrays as nested lists); inverse of :meth:`from_dict`."""
        out = {k: v for k, v in asdict(self).items() if k != "walls"}
        out["walls"] = [
            {
                "name": w.name,
                "vertices": w.vertices.tolist(),
                "faces": w.faces.tolist(),
                "motion": asdict(w.motion),
                "removal_time": w.removal_time,
            }
            for w in self.walls
        ]
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Scene:
        data = dict(data)
        walls = [
            Wall(
                name=w["name"],
                vertices=np.asarray(w["vertices"], float),
                faces=np.asarray(w["faces"], np.int64),
                motion=WallMotion(**{k: _tuple(v) for k, v in w["motion"].items()}),
                removal_time=w["removal_time"],
            )
            for w in data.pop("walls")
        ]
        particles = ParticleSpec(**{k: _tuple(v) for k, v in data.pop("particles").items()})
        materials = Materials(**data.pop("materials"))
        for key in ("gravity", "domain_lo", "domain_hi"):
            data[key] = _tuple(data[key])
        return cls(walls=walls, particles=particles, materials=materials, **data)


def _tuple(value):
    return tuple(value) if isinstance(value, list) else value
