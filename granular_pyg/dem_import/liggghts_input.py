"""Read what made a LIGGGHTS run from its input script or its log (LIGGGHTS-PUBLIC syntax).

From the commands, in order, with the DEM step counted through ``run N`` (``upto``),
``reset_timestep N`` and, in a log, the first row of every thermo table:

* ``timestep dt``; ``units`` (only ``si`` is accepted);
* materials: ``fix ... property/global youngsModulus peratomtype ...``, ``poissonsRatio``
  (``peratomtype``), ``coefficientRestitution``, ``coefficientFriction``,
  ``coefficientRollingFriction`` (``peratomtypepair n ...``), read for the particles' atom
  type, and the density of ``fix ... particletemplate/sphere ... atom_type k density constant
  X``;
* gravity: ``fix ... gravity g vector x y z`` (the vector is normalised, as LIGGGHTS does);
* meshes: ``fix <id> all mesh/surface file <stl> [scale s] [move dx dy dz] [rotate axis ax ay
  az angle deg]`` (the transforms applied in the order given, about the origin, as LIGGGHTS
  does), which of them are walls (named in a ``wall/gran ... meshes`` list), and ``unfix
  <id>``: the wall's removal at the current step;
* motions: ``fix <id> all move/mesh mesh <mesh id> rotate origin px py pz axis ax ay az period
  P`` (``omega = 2 pi / P``, right-handed about the axis), ``linear vx vy vz``, ``wiggle
  amplitude ax ay az period P``, from the step the fix is given until ``unfix <id>``.

Variables: in a script, ``${name}`` / ``$x`` are replaced by the value of a ``variable name
(equal|index|string|...) value`` with a single value; anything else (an expression, a
variable of another style) is refused with a message when a value that is needed uses it. A log
holds every command twice when it used a variable (as written, then substituted): the written
one is skipped. ``include`` is followed; loops (``jump``, ``label``, ``next``) and ``if`` are
refused in a script (pass its log instead).
"""

from __future__ import annotations

import itertools
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from granular_pyg.errors import InputError
from granular_pyg.scenes.scene import WallMotion

__all__ = ["MeshFix", "MeshMove", "RunScript", "read_run_script"]

#: ``property/global`` names -> Materials fields (pair coefficients marked).
MATERIAL_PROPERTIES = {
    "youngsModulus": ("youngs_modulus", False),
    "poissonsRatio": ("poisson_ratio", False),
    "coefficientRestitution": ("restitution", True),
    "coefficientFriction": ("friction", True),
    "coefficientRollingFriction": ("rolling_friction", True),
}
_COMMANDS = {
    "units",
    "timestep",
    "run",
    "reset_timestep",
    "read_restart",
    "fix",
    "unfix",
    "variable",
    "include",
    "jump",
    "label",
    "next",
    "if",
}
_VARIABLE = re.compile(r"\$\{([^}]*)\}|\$\(([^)]*)\)|\$([A-Za-z0-9_])")
_UNSET = "\x00var:"  # marks a token whose variable could not be replaced


@dataclass
class MeshFix:
    """A ``fix mesh/surface``.

    Attributes:
        fix_id: the fix (mesh) id.
        file: the mesh file, resolved against the script's folder.
        ops: the load transforms in order: ``("scale", s)``, ``("move", (dx, dy, dz))`` (m),
            ``("rotate", (ax, ay, az), degrees)``.
        where: ``"file:line"`` of the command.
        step: DEM step at which it was given (None when unknown, after ``read_restart``).
        is_wall: named in a ``wall/gran ... meshes`` list.
        removed_step: step of its ``unfix`` (None: never removed, or unknown).
        removed_where: ``"file:line"`` of that ``unfix``.
    """

    fix_id: str
    file: Path
    ops: list[tuple]
    where: str
    step: int | None
    is_wall: bool = False
    removed_step: int | None = None
    removed_where: str | None = None
    removed_known: bool = True

    def transform(self, points: np.ndarray) -> np.ndarray:
        """``[P, 3]`` the mesh points (m) after the load transforms, as LIGGGHTS applies them."""
        out = np.asarray(points, np.float64)
        for op in self.ops:
            if op[0] == "scale":
                out = out * op[1]
            elif op[0] == "move":
                out = out + np.asarray(op[1])
            else:
                rot, _ = WallMotion("rotation", axis=op[1], omega=1.0).pose(math.radians(op[2]))
                out = out @ rot.T
        return out


@dataclass
class MeshMove:
    """A ``fix move/mesh``.

    Attributes:
        fix_id: the fix id.
        mesh_id: the moved mesh.
        motion: its motion with ``start_time = 0`` and no stop (times are set by
            :meth:`RunScript.motion_for`), or None for an unsupported style.
        problem: why ``motion`` is None.
        where: ``"file:line"`` of the command.
        start_step: DEM step at which it was given (None when unknown).
        stop_step: step of its ``unfix`` (None: never stopped).
        stop_known: False when the step of its ``unfix`` is unknown.
    """

    fix_id: str
    mesh_id: str
    motion: WallMotion | None
    problem: str
    where: str
    start_step: int | None
    stop_step: int | None = None
    stop_known: bool = True


@dataclass
class RunScript:
    """What a LIGGGHTS input script or log says about the run; see the module docstring.

    Values are stored with the ``"file:line"`` they came from, for messages.
    """

    path: Path
    is_log: bool
    timesteps: list[tuple[float, str]] = field(default_factory=list)
    gravity: tuple[tuple[float, float, float], str] | None = None
    properties: dict[str, tuple[str, list[float], str]] = field(default_factory=dict)
    templates: list[tuple[int | None, float | None, str]] = field(default_factory=list)
    meshes: dict[str, MeshFix] = field(default_factory=dict)
    moves: list[MeshMove] = field(default_factory=list)
    #: Commands that could not be read, raised only when their value is needed: keys
    #: ``"timestep"``, ``"gravity"``, ``"density"``, ``"material:<name>"``, ``"mesh:<id>"``,
    #: ``"step"`` (why the DEM step became unknown).
    problems: dict[str, str] = field(default_factory=dict)

    @property
    def what(self) -> str:
        """``"input script X"`` or ``"log X"``."""
        return f"{'log' if self.is_log else 'input script'} {self.path}"

    @property
    def timestep(self) -> tuple[float, str] | None:
        """``(dt (s), where)`` of the run's time step, or None if the script sets none.

        Raises:
            InputError: the script changes the time step (times cannot be counted in steps).
        """
        if "timestep" in self.problems:
            raise InputError(self.problems["timestep"])
        if not self.timesteps:
            return None
        values = {dt for dt, _ in self.timesteps}
        if len(values) > 1:
            listed = ", ".join(f"{dt:g} s ({where})" for dt, where in self.timesteps)
            raise InputError(
                f"{self.what}: the time step changes during the run ({listed}); times cannot "
                "be counted in steps: convert the parts of one time step separately"
            )
        return self.timesteps[0]

    def particle_types(self, dump_types: set[int] | None = None) -> set[int]:
        """Atom types of the particles: those of the ``particletemplate/sphere`` fixes, else
        ``dump_types`` (the dump's ``type`` column), else ``{1}``."""
        types = {t for t, _, _ in self.templates if t is not None}
        return types or set(dump_types or ()) or {1}

    def materials(
        self, particle_types: set[int], skip: frozenset[str] = frozenset()
    ) -> dict[str, tuple[float, str]]:
        """The :class:`~granular_pyg.scenes.Materials` fields the script sets, as
        ``{field: (value, where)}``, read for ``particle_types``.

        Args:
            particle_types: the particles' atom types (see :meth:`particle_types`).
            skip: fields given elsewhere (walls.yaml): not read, so a conflict there does not
                matter.

        Raises:
            InputError: a property that differs between the particle types, a table too short
                for a type, or particle templates of different (or unreadable) densities.
        """
        out: dict[str, tuple[float, str]] = {}
        types = sorted(particle_types)
        for name, (style, values, where) in self.properties.items():
            key, pair = MATERIAL_PROPERTIES[name]
            if key in skip:
                continue
            if f"material:{name}" in self.problems:
                raise InputError(self.problems[f"material:{name}"])
            if pair:
                if style != "peratomtypepair" or not values:
                    raise InputError(f"{where}: {name} must be 'peratomtypepair n ...'")
                n = int(values[0])
                table = values[1:]
                if len(table) != n * n:
                    raise InputError(
                        f"{where}: {name} peratomtypepair {n} needs {n * n} values, got "
                        f"{len(table)}"
                    )
                inside = [t for t in types if t <= n]
                found = {table[(a - 1) * n + (b - 1)] for a in inside for b in inside}
            else:
                if style != "peratomtype":
                    raise InputError(f"{where}: {name} must be 'peratomtype ...'")
                n = len(values)
                inside = [t for t in types if t <= n]
                found = {values[t - 1] for t in inside}
            if len(inside) < len(types):
                raise InputError(
                    f"{where}: {name} lists {n} atom type(s), but the particles have atom "
                    f"type(s) {types}"
                )
            if len(found) > 1:
                raise InputError(
                    f"{where}: {name} differs between the particles' atom types {types} "
                    f"({sorted(found)}); a Scene has one material: set materials.{key} in "
                    "walls.yaml (--walls)"
                )
            out[key] = (found.pop(), where)
        if "density" not in skip and "density" in self.problems:
            raise InputError(self.problems["density"])
        if "density" not in skip and self.templates:
            values = {d for _, d, _ in self.templates if d is not None}
            unreadable = [w for _, d, w in self.templates if d is None]
            if len(values) > 1 or unreadable:
                listed = ", ".join(
                    f"{'?' if d is None else f'{d:g}'} ({w})" for _, d, w in self.templates
                )
                raise InputError(
                    f"{self.what}: the particle templates give no single density ({listed}; "
                    "only 'density constant X' is read); set materials.density in walls.yaml "
                    "(--walls)"
                )
            where = self.templates[0][2]
            out["density"] = (values.pop(), where)
        return out

    def motion_for(self, mesh_id: str, dem_dt: float) -> tuple[WallMotion, str] | None:
        """The motion of mesh ``mesh_id`` in absolute time (``step * dem_dt``), with its
        ``where``; None if no ``move/mesh`` fix moves it.

        Raises:
            InputError: an unsupported ``move/mesh`` style, two motions on the mesh, or a
                start or stop at an unknown step (after ``read_restart`` in a script).
        """
        moves = [m for m in self.moves if m.mesh_id == mesh_id]
        if not moves:
            return None
        for move in moves:
            if move.motion is None:
                problem = move.problem
                raise InputError(
                    problem if problem.startswith(move.where) else f"{move.where}: {problem}"
                )
            if move.start_step is None or not move.stop_known:
                raise InputError(
                    f"{move.where}: the step at which this motion starts or stops is unknown "
                    f"({self.problems.get('step', 'no step count')}); pass the run's log "
                    "(--log) or give the motion in walls.yaml (--walls)"
                )
        moves = [m for m in moves if m.stop_step is None or m.stop_step > m.start_step]
        if not moves:
            return None  # stopped before it moved
        if len(moves) > 1 and not _reverses(moves):
            listed = ", ".join(m.where for m in moves)
            raise InputError(
                f"{self.what}: mesh {mesh_id} has {len(moves)} move/mesh fixes ({listed}); a "
                "wall has one motion (or one rotation whose fixes follow each other, each "
                "turning back at the same speed): give the motion that matters in walls.yaml "
                "(--walls)"
            )
        first, last = moves[0], moves[-1]
        stop = None if last.stop_step is None else last.stop_step * dem_dt
        fields = {k: getattr(first.motion, k) for k in ("kind", "axis", "origin", "omega")}
        fields |= {k: getattr(first.motion, k) for k in ("velocity", "amplitude", "period")}
        flips = tuple(m.start_step * dem_dt for m in moves[1:])
        motion = WallMotion(
            **fields, start_time=first.start_step * dem_dt, stop_time=stop, reverse_times=flips
        )
        return motion, first.where


def _reverses(moves: list[MeshMove]) -> bool:
    """Whether ``moves`` (in script order, steps known) are one rotation turned back and forth:
    each fix starts at the step the one before stopped, about the same axis line at the same
    speed, turning the other way."""
    for a, b in itertools.pairwise(moves):
        ma, mb = a.motion, b.motion
        if ma.kind != "rotation" or mb.kind != "rotation" or a.stop_step != b.start_step:
            return False
        axis_a = np.asarray(ma.axis) / np.linalg.norm(ma.axis)
        axis_b = np.asarray(mb.axis) / np.linalg.norm(mb.axis)
        offset = np.asarray(mb.origin) - np.asarray(ma.origin)
        scale = max(1.0, float(np.abs(ma.origin).max()))
        if not (
            np.allclose(axis_b, -axis_a, atol=1e-9)
            and np.linalg.norm(np.cross(offset, axis_a)) <= 1e-9 * scale
            and math.isclose(ma.omega, mb.omega, rel_tol=1e-9)
        ):
            return False
    return True


def read_run_script(path: str | os.PathLike, is_log: bool | None = None) -> RunScript:
    """Read a LIGGGHTS input script or log.

    Args:
        path: the file.
        is_log: whether it is a log (commands echoed among the output); by default a file
            whose text holds ``LIGGGHTS (Version`` is a log.

    Returns:
        The :class:`RunScript`.

    Raises:
        FileNotFoundError: ``path`` (or an ``include``d file) does not exist.
        InputError: a command this reader needs that it cannot read (naming the file, line and
            the fix), ``units`` other than ``si``, loops in a script, or a log without echoed
            commands.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such LIGGGHTS input script or log; check the path")
    text = path.read_text(encoding="utf-8", errors="replace")
    if is_log is None:
        is_log = "LIGGGHTS (Version" in text or "LAMMPS (" in text[:200]
    parser = _Parser(RunScript(path=path, is_log=is_log), path.parent)
    parser.feed(path, text)
    if is_log and parser.commands == 0:
        raise InputError(
            f"{path}: no echoed commands in this log (was 'echo none' set?); pass the input "
            "script (--input) instead"
        )
    return parser.script


class _Parser:
    """Walks the commands of a script (and its includes) or a log, counting DEM steps."""

    def __init__(self, script: RunScript, folder: Path) -> None:
        self.script = script
        self.folder = folder
        self.step: int | None = 0
        self.variables: dict[str, str | None] = {}
        self.commands = 0
        self.thermo_header = False
        self.last_run: tuple[int, bool] | None = None  # (N, upto) of the last 'run'

    # -- lines ---------------------------------------------------------------------------

    def feed(self, path: Path, text: str) -> None:
        for number, line in _logical_lines(text):
            where = f"{path}:{number}"
            words = line.split()
            if not words:
                continue
            if self.script.is_log and self._thermo(words):
                continue
            command = words[0]
            if command not in _COMMANDS:
                continue
            if self.script.is_log and "$" in line:
                continue  # the substituted copy follows
            self.commands += 1
            if not self.script.is_log:
                words = self._substitute(words, where)
            getattr(self, "_" + command)(words, where, path)

    def _thermo(self, words: list[str]) -> bool:
        """In a log: the first row of a thermo table (``Step ...`` header) is the step the last
        ``run`` started from (it sets the step after a ``read_restart``)."""
        if words[0] == "Step":
            self.thermo_header = True
            return True
        if self.thermo_header:
            self.thermo_header = False
            if re.fullmatch(r"\d+", words[0]):
                start = int(words[0])  # the step the last 'run' started from
                n, upto = self.last_run or (0, False)
                self.step = n if upto else start + n
                self.last_run = None
                return True
        return False

    def _substitute(self, words: list[str], where: str) -> list[str]:
        if words[0] == "variable":
            return words
        out = []
        for word in words:
            if "$" not in word:
                out.append(word)
                continue

            def value(match: re.Match) -> str:
                name = match.group(1) or match.group(3)
                known = self.variables.get(name) if name else None
                if known is None:
                    return _UNSET + match.group(0)
                return known

            out.append(_VARIABLE.sub(value, word))
        return out

    # -- commands ------------------------------------------------------------------------

    def _variable(self, words, where, path) -> None:
        if len(words) >= 3:
            values = words[3:]
            ok = len(values) >= 1 and "$" not in values[0] and "v_" not in values[0]
            if words[2] in ("equal", "string", "index") and len(values) == 1 and ok:
                value = values[0].strip("\"'")
                if words[2] == "equal" and not _is_number(value):
                    value = None  # an expression
                self.variables[words[1]] = value
            elif words[2] == "index" and ok:
                self.variables[words[1]] = values[0]
            else:
                self.variables[words[1]] = None

    def _units(self, words, where, path) -> None:
        if len(words) < 2 or words[1] != "si":
            raise InputError(
                f"{where}: 'units {' '.join(words[1:])}': only LIGGGHTS runs in SI units "
                "('units si') can be imported"
            )

    def _timestep(self, words, where, path) -> None:
        try:
            self.script.timesteps.append((_number(words, 1, where), where))
        except InputError as err:
            self.script.problems["timestep"] = str(err)

    def _run(self, words, where, path) -> None:
        try:
            n = int(_number(words, 1, where))
        except InputError as err:
            self.step, self.last_run = None, None
            self.script.problems["step"] = f"a run of unknown length: {err}"
            return
        upto = "upto" in words[2:]
        self.last_run = (n, upto)
        if self.step is not None:
            self.step = n if upto else self.step + n

    def _reset_timestep(self, words, where, path) -> None:
        try:
            self.step = int(_number(words, 1, where))
        except InputError as err:
            self.step, self.script.problems["step"] = None, str(err)

    def _read_restart(self, words, where, path) -> None:
        self.step = None  # a log's next thermo table tells it
        self.script.problems["step"] = f"{where}: read_restart: the step it restores is unknown"

    def _include(self, words, where, path) -> None:
        if self.script.is_log:
            return  # the log holds the included commands
        included = self.folder / words[1]
        if not included.is_file():
            raise FileNotFoundError(f"{where}: 'include {words[1]}': no such file {included}")
        self.feed(included, included.read_text(encoding="utf-8", errors="replace"))

    def _loop(self, words, where, path) -> None:
        if not self.script.is_log:
            raise InputError(
                f"{where}: '{words[0]}': loops and conditions are not read from an input "
                "script; pass the run's log instead (--log), which lists every command run"
            )

    _jump = _label = _next = _if = _loop

    def _unfix(self, words, where, path) -> None:
        fix_id = words[1] if len(words) > 1 else ""
        mesh = self.script.meshes.get(fix_id)
        if mesh is not None and mesh.removed_where is None:
            mesh.removed_step, mesh.removed_where = self.step, where
            mesh.removed_known = self.step is not None
        for move in self.script.moves:
            if move.fix_id == fix_id and move.stop_step is None and move.stop_known:
                move.stop_step = self.step
                move.stop_known = self.step is not None

    def _fix(self, words, where, path) -> None:
        if len(words) < 4:
            return
        fix_id, style, args = words[1], words[3], words[4:]
        try:
            self._fix_style(fix_id, style, args, where)
        except InputError as err:  # raised when the value is needed (see RunScript.problems)
            if style == "property/global" and args:
                self.script.problems[f"material:{args[0]}"] = str(err)
                self.script.properties[args[0]] = ("", [], where)
            elif style.startswith("particletemplate/"):
                self.script.problems["density"] = str(err)
            elif style == "gravity":
                self.script.problems["gravity"] = str(err)
            elif style.startswith("mesh/surface"):
                self.script.problems[f"mesh:{fix_id}"] = str(err)
            elif style == "move/mesh":
                mesh_id = args[1] if len(args) > 1 else ""
                move = MeshMove(fix_id, mesh_id, None, str(err), where, self.step)
                self.script.moves.append(move)
            else:
                raise

    def _fix_style(self, fix_id: str, style: str, args: list[str], where: str) -> None:
        if style == "property/global" and args:
            name = args[0]
            if name in MATERIAL_PROPERTIES:
                kind = args[1] if len(args) > 1 else ""
                values = [_number(args, k, where) for k in range(2, len(args))]
                self.script.properties[name] = (kind, values, where)
        elif style.startswith("particletemplate/"):
            self._template(args, where)
        elif style == "gravity":
            self._gravity(args, where)
        elif style.startswith("mesh/surface"):
            self._mesh(fix_id, args, where)
        elif style == "move/mesh":
            self._move(fix_id, args, where)
        elif style.startswith("wall/gran") and "meshes" in args:
            # 'mesh n_meshes k meshes <ids> [keywords]': the known mesh ids after 'meshes'
            for mesh_id in args[args.index("meshes") + 1 :]:
                if mesh_id in self.script.meshes:
                    self.script.meshes[mesh_id].is_wall = True

    def _template(self, args: list[str], where: str) -> None:
        atom_type = (
            int(_number(args, args.index("atom_type") + 1, where))
            if ("atom_type" in args)
            else None
        )
        density = None
        if "density" in args:
            k = args.index("density")
            if k + 2 < len(args) and args[k + 1] == "constant":
                density = _number(args, k + 2, where)
        self.script.templates.append((atom_type, density, where))

    def _gravity(self, args: list[str], where: str) -> None:
        if len(args) >= 5 and args[1] == "vector":
            g = _number(args, 0, where)
            vec = np.array([_number(args, k, where) for k in (2, 3, 4)])
            norm = float(np.linalg.norm(vec))
            if norm == 0:
                raise InputError(f"{where}: gravity vector 0 0 0 has no direction")
            self.script.gravity = (tuple(float(v) for v in g * vec / norm), where)
        else:
            raise InputError(
                f"{where}: gravity style '{' '.join(args[1:2])}' is not read (only 'gravity g "
                "vector x y z'); pass --gravity"
            )

    def _mesh(self, fix_id: str, args: list[str], where: str) -> None:
        if fix_id in self.script.meshes:
            first = self.script.meshes[fix_id].where
            raise InputError(
                f"{where}: mesh {fix_id} is defined a second time (first at {first}); "
                "re-defined meshes are not supported"
            )  # raised at once: the mesh order of the dumps would be unclear
        if len(args) < 2 or args[0] != "file":
            self.script.problems[f"mesh:{fix_id}"] = (
                f"{where}: mesh {fix_id} is not read from a file ('{' '.join(args[:2])}'); only "
                "'mesh/surface file <stl>' meshes can be imported"
            )
            return
        ops: list[tuple] = []
        k = 2
        while k < len(args):
            word = args[k]
            if word == "scale":
                ops.append(("scale", _number(args, k + 1, where)))
                k += 2
            elif word == "move":
                ops.append(("move", tuple(_number(args, k + i, where) for i in (1, 2, 3))))
                k += 4
            elif word == "rotate" and k + 6 < len(args) and args[k + 1] == "axis":
                axis = tuple(_number(args, k + i, where) for i in (2, 3, 4))
                ops.append(("rotate", axis, _number(args, k + 6, where)))
                k += 7
            else:
                k += 1
        self.script.meshes[fix_id] = MeshFix(fix_id, self.folder / args[1], ops, where, self.step)

    def _move(self, fix_id: str, args: list[str], where: str) -> None:
        if len(args) < 3 or args[0] != "mesh":
            raise InputError(f"{where}: expected 'move/mesh mesh <mesh id> <style> ...'")
        mesh_id, style, rest = args[1], args[2], args[3:]
        motion, problem = None, ""
        try:
            if style == "rotate" and rest[0] == "origin" and rest[4] == "axis":
                period = _number(rest, 9, where)
                motion = WallMotion(
                    "rotation",
                    origin=tuple(_number(rest, i, where) for i in (1, 2, 3)),
                    axis=tuple(_number(rest, i, where) for i in (5, 6, 7)),
                    omega=2 * math.pi / period,
                )
            elif style == "linear":
                velocity = tuple(_number(rest, i, where) for i in (0, 1, 2))
                motion = WallMotion("translation", velocity=velocity)
            elif style == "wiggle" and rest[0] == "amplitude" and rest[4] == "period":
                motion = WallMotion(
                    "oscillation",
                    amplitude=tuple(_number(rest, i, where) for i in (1, 2, 3)),
                    period=_number(rest, 5, where),
                )
            else:
                problem = (
                    f"move/mesh style '{style}' is not imported (only rotate, linear and "
                    "wiggle); give the wall's motion in walls.yaml (--walls)"
                )
        except IndexError:
            raise InputError(f"{where}: too few values for 'move/mesh ... {style}'") from None
        self.script.moves.append(MeshMove(fix_id, mesh_id, motion, problem, where, self.step))


def _logical_lines(text: str):
    """``(first line number, command)``: comments removed, ``&`` continuations joined."""
    pending, start = "", 0
    for number, raw in enumerate(text.splitlines(), 1):
        line = _strip_comment(raw).rstrip()
        if not pending:
            start = number
        if line.endswith("&"):
            pending += line[:-1] + " "
            continue
        yield start, pending + line
        pending = ""
    if pending:
        yield start, pending


def _strip_comment(line: str) -> str:
    quote = None
    for k, ch in enumerate(line):
        if ch in "\"'":
            quote = None if quote == ch else (ch if quote is None else quote)
        elif ch == "#" and quote is None:
            return line[:k]
    return line


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _number(words: list[str], k: int, where: str) -> float:
    """``float(words[k])`` or an InputError naming the line and the value."""
    if k >= len(words):
        raise InputError(f"{where}: '{' '.join(words)}' has too few values")
    word = words[k]
    if _UNSET in word:
        name = word.split(_UNSET, 1)[1]
        raise InputError(
            f"{where}: {name} is a variable whose value cannot be read from the script (an "
            "expression, a variable of another style, or undefined); pass the run's log (--log), "
            "where LIGGGHTS writes the substituted command, or give the value on the command line"
            " or in walls.yaml"
        )
    try:
        value = float(word)
    except ValueError:
        raise InputError(f"{where}: expected a number, got {word!r}") from None
    if not math.isfinite(value):
        raise InputError(f"{where}: expected a finite number, got {word!r}")
    return value
