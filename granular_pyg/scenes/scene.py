"""The Scene: the single description of a set-up, shared by LIGGGHTS and the learned simulator.

A :class:`Scene` holds named triangle-mesh walls, each with a motion (static, or a rigid rotation,
translation or oscillation: :class:`WallMotion`) and an optional removal time, the particles to
insert (one radius or a discrete size distribution, in a box or a vertical cylinder), gravity,
the outflow rule, the materials, the DEM/recording times and the set-up's ``kind``.
``granular_pyg.dem`` renders it into a LIGGGHTS input script; ``granular_pyg.simulator`` rolls
the learned model out over the same Scene, so the two can never disagree about geometry.

Time convention: ``t = 0`` is the first recorded frame. LIGGGHTS first fills and settles the
particles for ``settle_time`` seconds (not recorded) with every wall at its ``t = 0`` pose;
wall motions and removals are given in recorded time.

Outflow rule: a particle whose centre drops below ``outflow_z`` leaves the scene for good. In
LIGGGHTS the simulation box ends at ``outflow_z`` (``boundary f f f`` with lost atoms ignored),
so the particle is deleted there; the learned simulator applies the same test, and a Trajectory
stores NaN for a particle from the first frame it is gone.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from granular_pyg.errors import InputError

__all__ = [
    "FILL_SHAPES",
    "MOTION_KINDS",
    "SCENE_KINDS",
    "Materials",
    "ParticleSpec",
    "Scene",
    "Wall",
    "WallMotion",
]


#: Motions a wall can have; each maps onto one ``fix move/mesh`` style in LIGGGHTS.
MOTION_KINDS = ("static", "rotation", "translation", "oscillation")
#: Scene kinds: the two reference set-ups, or anything else.
SCENE_KINDS = ("hopper", "drum", "other")


@dataclass(frozen=True)
class WallMotion:
    """Rigid motion of a wall, in recorded time; each kind is one LIGGGHTS ``fix move/mesh``.

    * ``static``: never moves.
    * ``rotation`` (``rotate``): about ``axis`` through ``origin`` at ``omega``.
    * ``translation`` (``linear``): at the constant ``velocity``.
    * ``oscillation`` (``wiggle``): displacement ``amplitude * sin(2 pi (t - start_time) /
      period)``.

    Every motion starts at ``start_time`` (the wall rests at its mesh pose before) and, when
    ``stop_time`` is given, stops there and keeps the pose it reached. A rotation may reverse
    its sense at ``reverse_times`` (a drum turned back and forth; one more ``fix move/mesh``
    each). Fields that do not belong to the kind are ignored (their defaults are stored).

    Attributes:
        kind: one of :data:`MOTION_KINDS`.
        axis: rotation axis ``[3]`` (unit vector after normalisation), right-handed.
        origin: a point on the rotation axis ``[3]`` (m).
        omega: angular velocity (rad/s), the sign follows the right-hand rule about ``axis``.
        start_time: recorded time (s, >= 0) at which the motion starts.
        velocity: translation velocity ``[3]`` (m/s).
        amplitude: oscillation amplitude ``[3]`` (m).
        period: oscillation period (s, > 0 for an oscillation).
        stop_time: recorded time (s, > start_time) at which the motion stops, or None (never).
        reverse_times: recorded times (s, increasing, between ``start_time`` and
            ``stop_time``) at which a rotation turns the other way at the same ``|omega|``;
            empty: never.
    """

    kind: str = "static"
    axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    omega: float = 0.0
    start_time: float = 0.0
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    amplitude: tuple[float, float, float] = (0.0, 0.0, 0.0)
    period: float = 0.0
    stop_time: float | None = None
    reverse_times: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in MOTION_KINDS:
            raise InputError(f"motion.kind: expected one of {MOTION_KINDS}, got {self.kind!r}")
        for name in ("axis", "origin", "velocity", "amplitude"):
            value = np.asarray(getattr(self, name), float)
            if value.shape != (3,) or not np.isfinite(value).all():
                raise InputError(
                    f"motion.{name}: expected 3 finite numbers, got {getattr(self, name)!r}"
                )
            object.__setattr__(self, name, tuple(float(v) for v in value))
        if self.kind == "rotation" and not np.any(np.asarray(self.axis, float)):
            raise InputError("motion.axis: a rotation needs a non-zero axis")
        if not (math.isfinite(self.start_time) and self.start_time >= 0):
            raise InputError(
                f"motion.start_time: expected a recorded time >= 0 s, got {self.start_time}"
            )
        if self.stop_time is not None and not self.stop_time > self.start_time:
            raise InputError(
                f"motion.stop_time ({self.stop_time} s) must come after start_time "
                f"({self.start_time} s); use None for a motion that never stops"
            )
        if self.kind == "oscillation" and not (math.isfinite(self.period) and self.period > 0):
            raise InputError(
                f"motion.period: an oscillation needs a positive period (s), got {self.period}"
            )
        self._check_reverse_times()

    def _check_reverse_times(self) -> None:
        times = tuple(float(t) for t in np.atleast_1d(np.asarray(self.reverse_times, float)))
        object.__setattr__(self, "reverse_times", times)
        if not times:
            return
        if self.kind != "rotation":
            raise InputError(
                f"motion.reverse_times: only a rotation reverses, this motion is a {self.kind}; "
                "drop reverse_times"
            )
        stop = math.inf if self.stop_time is None else self.stop_time
        bounds = (self.start_time, *times, stop)
        if not all(a < b for a, b in itertools.pairwise(bounds)):
            raise InputError(
                f"motion.reverse_times {list(times)}: expected increasing times between "
                f"start_time ({self.start_time} s) and stop_time ({self.stop_time} s)"
            )

    def to_dict(self) -> dict[str, Any]:
        """The fields as a dict; ``reverse_times`` only when the motion reverses (the files
        of motions that never do read as before it existed)."""
        out = asdict(self)
        if not self.reverse_times:
            del out["reverse_times"]
        return out

    def _elapsed(self, t: float) -> float:
        """Time (s) the motion has run by recorded time ``t``."""
        if self.stop_time is not None:
            t = min(t, self.stop_time)
        return max(0.0, t - self.start_time)

    def active(self, t: float) -> bool:
        """Whether the wall is moving at recorded time ``t`` (s): ``start <= t < stop``."""
        if self.kind == "static" or t < self.start_time:
            return False
        return self.stop_time is None or t < self.stop_time

    def _turned(self, t: float) -> float:
        """Time (s) the motion has run by recorded time ``t``, counted backwards while a
        rotation runs reversed (so ``omega * _turned(t)`` is its angle)."""
        elapsed = self._elapsed(t)
        if not self.reverse_times:
            return elapsed
        end = self.start_time + elapsed
        turned, sense, since = 0.0, 1.0, self.start_time
        for flip in self.reverse_times:
            if flip >= end:
                break
            turned += sense * (flip - since)
            sense, since = -sense, flip
        return turned + sense * (end - since)

    def angular_velocity(self, t: float) -> float:
        """Signed angular velocity (rad/s, right-handed about ``axis``) at recorded time ``t``
        (s): ``+-omega`` while a rotation runs (the sign flips at each reverse time), else 0."""
        if self.kind != "rotation" or not self.active(t):
            return 0.0
        flips = sum(1 for flip in self.reverse_times if flip <= t)
        return -self.omega if flips % 2 else self.omega

    def mean_angular_velocity(self, t0: float, t1: float) -> float:
        """Mean signed angular velocity (rad/s) of a rotation over the recorded times
        ``[t0, t1]`` (s, ``t1 > t0``): its turn between them over ``t1 - t0``; 0 otherwise."""
        if self.kind != "rotation" or not t1 > t0:
            return 0.0
        return self.omega * (self._turned(t1) - self._turned(t0)) / (t1 - t0)

    def mean_linear_velocity(self, t0: float, t1: float) -> np.ndarray:
        """``[3]`` mean velocity (m/s) of a translating or oscillating wall over the recorded
        times ``[t0, t1]`` (s, ``t1 > t0``): its shift between them over ``t1 - t0``; zeros
        for a wall that rests or rotates."""
        if self.kind not in ("translation", "oscillation") or not t1 > t0:
            return np.zeros(3)
        return (self.pose(t1)[1] - self.pose(t0)[1]) / (t1 - t0)

    def angle(self, t: float) -> float:
        """Rotation angle (rad) at recorded time ``t`` (s); 0 for other kinds."""
        if self.kind != "rotation":
            return 0.0
        return self.omega * self._turned(t)

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Pose at recorded time ``t`` (s): ``(rotation [3, 3], translation [3])`` with
        ``x_world = rotation @ x_mesh + translation``."""
        if self.kind == "translation":
            return np.eye(3), np.asarray(self.velocity, float) * self._elapsed(t)
        if self.kind == "oscillation":
            phase = 2 * math.pi * self._elapsed(t) / self.period
            return np.eye(3), np.asarray(self.amplitude, float) * math.sin(phase)
        angle = self.angle(t)
        if angle == 0.0:
            return np.eye(3), np.zeros(3)
        axis = np.asarray(self.axis, float)
        x, y, z = axis / np.linalg.norm(axis)
        k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
        rot = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)
        origin = np.asarray(self.origin, float)
        return rot, origin - rot @ origin

    def linear_velocity(self, t: float) -> np.ndarray:
        """``[3]`` velocity (m/s) of every point of a translating or oscillating wall at
        recorded time ``t`` (s); zeros when the wall rests or rotates (see
        :meth:`point_velocities`)."""
        if not self.active(t):
            return np.zeros(3)
        if self.kind == "translation":
            return np.asarray(self.velocity, float)
        if self.kind == "oscillation":
            rate = 2 * math.pi / self.period
            return np.asarray(self.amplitude, float) * rate * math.cos(rate * self._elapsed(t))
        return np.zeros(3)

    def point_velocities(self, points: np.ndarray, t: float) -> np.ndarray:
        """``[P, 3]`` velocity (m/s) at recorded time ``t`` (s) of the wall points at world
        positions ``points [P, 3]`` (m)."""
        points = np.asarray(points, float)
        if self.kind == "rotation" and self.active(t):
            axis = np.asarray(self.axis, float)
            omega = self.angular_velocity(t) * axis / np.linalg.norm(axis)
            return np.cross(omega, points - np.asarray(self.origin, float))
        return np.broadcast_to(self.linear_velocity(t), points.shape).copy()

    def swept_bounds(self, vertices: np.ndarray, t_end: float) -> tuple[np.ndarray, np.ndarray]:
        """``(lo [3], hi [3])`` (m): a box holding ``vertices [V, 3]`` (mesh frame, m) at every
        pose in the recorded times ``[0, t_end]`` (s); conservative for rotations and
        oscillations."""
        lo, hi = vertices.min(0), vertices.max(0)
        if self.kind == "rotation":
            # Every pose lies within the circles the vertices sweep about the axis.
            axis = np.asarray(self.axis, float)
            axis /= np.linalg.norm(axis)
            rel = vertices - np.asarray(self.origin)
            centres = np.asarray(self.origin) + np.outer(rel @ axis, axis)
            radial = np.linalg.norm(vertices - centres, axis=1).max()
            reach = radial * np.sqrt(np.clip(1.0 - axis**2, 0.0, 1.0))
            return centres.min(0) - reach, centres.max(0) + reach
        if self.kind == "translation":
            _, shift = self.pose(t_end)
            return np.minimum(lo, lo + shift), np.maximum(hi, hi + shift)
        if self.kind == "oscillation":
            reach = np.abs(np.asarray(self.amplitude, float))
            return lo - reach, hi + reach
        return lo, hi


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

    def swept_bounds(self, t_end: float) -> tuple[np.ndarray, np.ndarray]:
        """``(lo [3], hi [3])`` (m): a box holding the wall at every pose it takes while present
        in the recorded times ``[0, t_end]`` (s); see :meth:`WallMotion.swept_bounds`."""
        if self.removal_time is not None:
            t_end = min(t_end, self.removal_time)
        return self.motion.swept_bounds(self.vertices, max(0.0, t_end))


@dataclass(frozen=True)
class Materials:
    """Contact model parameters (Hertz with tangential history), SI units."""

    youngs_modulus: float = 5.0e6  # Pa
    poisson_ratio: float = 0.3
    restitution: float = 0.6
    friction: float = 0.5
    rolling_friction: float = 0.0  # 0 disables LIGGGHTS's rolling_friction cdt
    density: float = 2500.0  # kg/m^3


#: Shapes of the insertion region.
FILL_SHAPES = ("box", "cylinder")


@dataclass(frozen=True)
class ParticleSpec:
    """Particles to insert: ``count`` spheres rained into a region.

    Sizes: one ``radius`` (m), or a discrete distribution: ``radii`` (m) drawn with the number
    fractions ``radius_weights`` (normalised; equal when omitted), in which case ``radius`` is the
    largest of ``radii``.

    Region: ``fill_lo..fill_hi`` (m) is always its bounding box. ``fill_shape = "box"`` fills
    that box; ``"cylinder"`` fills the cylinder inscribed in it: axis along z through the box's
    x-y centre, radius half its x (= y) extent, from ``fill_lo`` z to ``fill_hi`` z (see
    :meth:`cylinder` and :meth:`cylinder_region`).

    Attributes:
        count: number of particles.
        radius: the particle radius (m); the largest radius for a distribution.
        fill_lo, fill_hi: ``[3]`` corners of the region's bounding box (m).
        radii: ``[K]`` radii (m) of a discrete size distribution, or None.
        radius_weights: ``[K]`` number fractions of ``radii`` (any positive scale), or None.
        fill_shape: one of :data:`FILL_SHAPES`.
    """

    count: int
    radius: float
    fill_lo: tuple[float, float, float]
    fill_hi: tuple[float, float, float]
    radii: tuple[float, ...] | None = None
    radius_weights: tuple[float, ...] | None = None
    fill_shape: str = "box"

    def __post_init__(self) -> None:
        if self.fill_shape not in FILL_SHAPES:
            raise InputError(
                f"particles.fill_shape: expected one of {FILL_SHAPES}, got {self.fill_shape!r}"
            )
        if self.fill_shape == "cylinder":
            ext = np.asarray(self.fill_hi, float) - np.asarray(self.fill_lo, float)
            if not math.isclose(ext[0], ext[1], rel_tol=1e-9, abs_tol=1e-15):
                raise InputError(
                    f"particles: a cylinder region needs a square x-y bounding box, got x extent "
                    f"{ext[0]} m and y extent {ext[1]} m; build it with "
                    "ParticleSpec.cylinder_region(...)"
                )
        if self.radii is None:
            if self.radius_weights is not None:
                raise InputError("particles.radius_weights: given without particles.radii")
            return
        radii = tuple(float(r) for r in self.radii)
        if not radii or not all(math.isfinite(r) and r > 0 for r in radii):
            raise InputError(f"particles.radii: expected positive radii (m), got {self.radii}")
        weights = self.radius_weights
        weights = (1.0,) * len(radii) if weights is None else tuple(float(w) for w in weights)
        if len(weights) != len(radii) or not all(math.isfinite(w) and w > 0 for w in weights):
            raise InputError(
                f"particles.radius_weights: expected {len(radii)} positive number fractions "
                f"(one per radius in {radii}), got {self.radius_weights}"
            )
        if self.radius != max(radii):
            raise InputError(
                f"particles.radius ({self.radius} m) must be the largest of radii {radii}"
            )
        object.__setattr__(self, "radii", radii)
        object.__setattr__(self, "radius_weights", weights)

    @classmethod
    def cylinder_region(
        cls,
        count: int,
        radius: float,
        centre: tuple[float, float],
        cylinder_radius: float,
        z_range: tuple[float, float],
        **sizes: Any,
    ) -> ParticleSpec:
        """A spec that fills the vertical cylinder of ``cylinder_radius`` (m) about the axis
        through ``centre`` ``[2]`` (x, y, m) between the heights ``z_range`` ``[2]`` (m);
        ``sizes`` are ``radii`` / ``radius_weights``."""
        cx, cy = (float(c) for c in centre)
        r = float(cylinder_radius)
        return cls(
            count=int(count),
            radius=float(radius),
            fill_lo=(cx - r, cy - r, float(z_range[0])),
            fill_hi=(cx + r, cy + r, float(z_range[1])),
            fill_shape="cylinder",
            **sizes,
        )

    @property
    def cylinder(self) -> tuple[float, float, float, float, float]:
        """``(centre x, centre y, radius, z low, z high)`` (m) of the cylinder region."""
        lo, hi = self.fill_lo, self.fill_hi
        return (
            0.5 * (lo[0] + hi[0]),
            0.5 * (lo[1] + hi[1]),
            0.5 * (hi[0] - lo[0]),
            float(lo[2]),
            float(hi[2]),
        )

    @property
    def size_distribution(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """``(radii [K] (m), number fractions [K] summing to 1)``; one entry for one radius."""
        if self.radii is None:
            return (float(self.radius),), (1.0,)
        total = sum(self.radius_weights)
        return self.radii, tuple(w / total for w in self.radius_weights)

    @property
    def fill_volume(self) -> float:
        """Volume of the insertion region (m^3)."""
        ext = np.asarray(self.fill_hi, float) - np.asarray(self.fill_lo, float)
        if self.fill_shape == "cylinder":
            return float(math.pi * (0.5 * ext[0]) ** 2 * ext[2])
        return float(np.prod(ext))

    @property
    def mean_volume(self) -> float:
        """Mean particle volume (m^3) over the size distribution."""
        radii, fractions = self.size_distribution
        return sum(f * 4.0 / 3.0 * math.pi * r**3 for r, f in zip(radii, fractions, strict=True))


@dataclass
class Scene:
    """A complete set-up; see the module docstring for the time and outflow conventions.

    Attributes:
        name: the scene's name, e.g. ``"hopper"``, ``"drum"`` or ``"mesh_silo"``.
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
        kind: what the set-up is, one of :data:`SCENE_KINDS`: ``"hopper"`` (particles drain
            through an outlet), ``"drum"`` (a closed rotating container) or ``"other"``. None
            (the default) takes ``name`` when it is ``"hopper"`` or ``"drum"``, else
            ``"other"``, so scenes stored before the field existed load unchanged.
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
    kind: str | None = None

    def __post_init__(self) -> None:
        if self.kind is None:
            self.kind = self.name if self.name in ("hopper", "drum") else "other"
        if self.kind not in SCENE_KINDS:
            raise InputError(
                f"scene {self.name}: kind must be one of {SCENE_KINDS}, got {self.kind!r}"
            )
        names = [w.name for w in self.walls]
        if len(set(names)) != len(names):
            raise InputError(f"scene {self.name}: wall names must be unique, got {names}")
        for key in ("dem_dt", "frame_dt"):
            value = getattr(self, key)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise InputError(
                    f"scene {self.name}: {key} must be a time step > 0 s, got {value!r}"
                )
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

    @property
    def opening_time(self) -> float | None:
        """Time (s) at which the outlet opens: the first wall removal (a hopper's lid); None
        when no wall is ever removed."""
        removals = [w.removal_time for w in self.walls if w.removal_time is not None]
        return float(min(removals)) if removals else None

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
                "motion": w.motion.to_dict(),
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
