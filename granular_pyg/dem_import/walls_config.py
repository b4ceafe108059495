"""``walls.yaml``: what a dump does not say about an imported run (``convert --walls``).

Example (every key optional)::

    kind: hopper              # hopper / drum / other
    name: my_hopper           # the Scene's name (default: the kind, or "imported")
    outflow_z: -0.03          # m: particles below leave for good
    gravity: [0, 0, -9.81]    # m/s^2
    units: m                  # default units of the STL files below: m, cm or mm
    materials:                # granular_pyg.scenes.Materials fields, SI units
      youngs_modulus: 5.0e6
      restitution: 0.6
      density: 2500
    walls:                    # STL file (relative to this file) -> its wall
      hopper.stl: {}
      lid.stl:
        removal_time: 0.05    # s, recorded time (t = 0 at the first dump frame)
      drum.stl:
        name: drum
        units: mm
        motion:               # granular_pyg.scenes.WallMotion fields, recorded time
          kind: rotation
          axis: [0, 1, 0]
          origin: [0, 0, 0]
          omega: 2.0          # rad/s, right-handed about the axis

An STL file's mesh is its pose at recorded time 0. Unknown keys are refused (a typo would
otherwise be ignored silently).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from granular_pyg.errors import InputError
from granular_pyg.scenes.scene import SCENE_KINDS, Materials, WallMotion

__all__ = ["UNITS", "WallEntry", "WallsConfig", "read_walls_config", "unit_scale"]

#: Length units of STL files -> metres per unit.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
_TOP_KEYS = ("kind", "name", "outflow_z", "gravity", "units", "materials", "walls")
_WALL_KEYS = ("file", "name", "motion", "removal_time", "units")
_MOTION_KEYS = tuple(f.name for f in dataclasses.fields(WallMotion))
_MATERIAL_KEYS = tuple(f.name for f in dataclasses.fields(Materials))


@dataclass
class WallEntry:
    """One wall of ``walls.yaml``.

    Attributes:
        file: the STL file, resolved against the YAML file's folder.
        where: ``"walls.yaml: walls[<key>]"`` for messages.
        name: the wall's name, or None (the file stem).
        motion: its motion in recorded time, or None (not given).
        removal_time: recorded time (s) at which it is removed, or None (not given).
        units: units of the STL file (a key of :data:`UNITS`), or None (not given).
    """

    file: Path
    where: str
    name: str | None = None
    motion: WallMotion | None = None
    removal_time: float | None = None
    units: str | None = None


@dataclass
class WallsConfig:
    """A parsed ``walls.yaml``; None for every value it does not give."""

    path: Path
    kind: str | None = None
    name: str | None = None
    outflow_z: float | None = None
    gravity: tuple[float, float, float] | None = None
    units: str | None = None
    materials: dict[str, float] = field(default_factory=dict)
    walls: list[WallEntry] = field(default_factory=list)


def unit_scale(units: str, where: str) -> float:
    """Metres per unit of ``units`` (``m``, ``cm``, ``mm``).

    Raises:
        InputError: other units, naming ``where``.
    """
    if units not in UNITS:
        raise InputError(f"{where}: units {units!r}: expected one of {list(UNITS)}")
    return UNITS[units]


def read_walls_config(path: str | os.PathLike) -> WallsConfig:
    """Read and check a ``walls.yaml``; see the module docstring for its keys.

    Raises:
        FileNotFoundError: the file does not exist.
        InputError: unreadable YAML, an unknown key (naming it and the allowed ones), or a
            value of the wrong type or range (naming the key).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such walls file; check --walls")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except yaml.YAMLError as err:
        raise InputError(f"{path}: not valid YAML ({err})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping of {list(_TOP_KEYS)} at the top level")
    _known(data, _TOP_KEYS, str(path))
    config = WallsConfig(path=path)
    if data.get("kind") is not None:
        if data["kind"] not in SCENE_KINDS:
            raise InputError(f"{path}: kind {data['kind']!r}: expected one of {SCENE_KINDS}")
        config.kind = data["kind"]
    if data.get("name") is not None:
        config.name = str(data["name"])
    if data.get("outflow_z") is not None:
        config.outflow_z = _float(data["outflow_z"], f"{path}: outflow_z")
    if data.get("gravity") is not None:
        config.gravity = _vector(data["gravity"], f"{path}: gravity")
    if data.get("units") is not None:
        unit_scale(data["units"], f"{path}: units")
        config.units = data["units"]
    materials = data.get("materials") or {}
    if not isinstance(materials, dict):
        raise InputError(f"{path}: materials must be a mapping of {list(_MATERIAL_KEYS)}")
    _known(materials, _MATERIAL_KEYS, f"{path}: materials")
    config.materials = {k: _float(v, f"{path}: materials.{k}") for k, v in materials.items()}
    walls = data.get("walls") or {}
    if isinstance(walls, dict):
        items = [(str(k), v or {}) for k, v in walls.items()]
    elif isinstance(walls, list):
        items = []
        for k, v in enumerate(walls):
            if not isinstance(v, dict) or "file" not in v:
                raise InputError(f"{path}: walls[{k}] needs a 'file' key (the STL file)")
            items.append((str(v["file"]), v))
    else:
        raise InputError(f"{path}: walls must map STL files to their settings")
    for key, entry in items:
        config.walls.append(_wall(path, key, entry))
    return config


def _wall(path: Path, key: str, entry: Any) -> WallEntry:
    where = f"{path}: walls[{key}]"
    if not isinstance(entry, dict):
        raise InputError(f"{where}: expected a mapping of {list(_WALL_KEYS)}")
    _known(entry, _WALL_KEYS, where)
    out = WallEntry(file=path.parent / key, where=where)
    if entry.get("name") is not None:
        out.name = str(entry["name"])
    if entry.get("units") is not None:
        unit_scale(entry["units"], f"{where}.units")
        out.units = entry["units"]
    if entry.get("removal_time") is not None:
        out.removal_time = _float(entry["removal_time"], f"{where}.removal_time")
        if out.removal_time < 0:
            raise InputError(f"{where}.removal_time: expected a recorded time >= 0 s")
    motion = entry.get("motion")
    if motion is not None:
        if not isinstance(motion, dict):
            raise InputError(f"{where}.motion: expected a mapping of {list(_MOTION_KEYS)}")
        _known(motion, _MOTION_KEYS, f"{where}.motion")
        values = {
            k: tuple(_number_text(x) for x in v) if isinstance(v, list) else _number_text(v)
            for k, v in motion.items()
        }
        try:
            out.motion = WallMotion(**values)
        except (InputError, TypeError, ValueError) as err:
            raise InputError(f"{where}.{err}") from None
    return out


def _known(data: dict, keys: tuple[str, ...], where: str) -> None:
    unknown = [k for k in data if k not in keys]
    if unknown:
        raise InputError(f"{where}: unknown key(s) {unknown}; expected some of {list(keys)}")


def _float(value: Any, where: str) -> float:
    value = _number_text(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{where}: expected a number, got {value!r}")
    if not np.isfinite(value):
        raise InputError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _number_text(value: Any) -> Any:
    """``value`` as a float when it is text of a number (YAML 1.1 reads ``5.0e6``, without a
    sign in the exponent, as text), else unchanged."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _vector(value: Any, where: str) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise InputError(f"{where}: expected 3 numbers, got {value!r}")
    x, y, z = (_float(v, where) for v in value)
    return (x, y, z)
