"""The learned simulator: features from the state, the network, and time integration.

**Features are built here and only here**, for training and rollout alike (a train/rollout
feature mismatch is the classic silent bug of learned simulators). For one time ``t``:

- graph: particles within ``radius`` of each other (both directions) plus one virtual wall node
  per (particle, triangle) pair within ``radius`` (wall -> particle edges), see
  :class:`~granular_pyg.transforms.AddWallNodes`;
- node features ``[3 H + 6 + 2]``: the last ``H`` velocities (finite differences of positions,
  m/s, normalised by the training statistics; for a wall node the wall's own velocity at the
  node, repeated), the six normal features of the variant (V1/V2/V3; zeros for particles),
  and the type one-hot (particle, wall); a wall node's features are
  multiplied by its weight (1/k with ``wall_weight``);
- optional particle-property columns after those (model options, off by default, so a model
  without them is unchanged): ``radius_feature`` adds the particle's radius / ``R`` (0 on wall
  nodes), ``material_features`` one column per named field of the Scene's
  :class:`~granular_pyg.scenes.Materials`, broadcast to every node and scaled by the fixed map
  :data:`MATERIAL_FEATURES` (no statistics), not weighted; they come in a
  :class:`ParticleProps`;
- edge features ``[4]`` for an edge ``j -> i``: ``(x_i - x_j) / R`` and ``|x_i - x_j| / R``;
  with the model option ``contact_feature`` a fifth, the distance in units of the contact
  distance, ``|x_i - x_j| / (r_i + r_j)`` (``r`` 0 for a wall node): 1 where two particles
  touch or a particle touches a wall, whatever the particles' size.

With the equivariant processor (``model/processor=equivariant``,
:class:`~granular_pyg.nn.HorizontalEquivariantProcessor`) the same quantities enter split into
scalars and horizontal vectors (see :meth:`LearnedSimulator._equivariant_features`), so the
prediction turns and mirrors with the scene exactly.

Every feature can be built in a turned or mirrored frame ``Q`` (``frame`` of
:meth:`LearnedSimulator.build_graph`, a ``[3, 3]`` orthogonal matrix fixing the z axis):
positions, velocities, wall velocities and normals are expressed in it, and
:meth:`LearnedSimulator.predict_acceleration` turns the prediction back. Training draws one
such frame per window (data augmentation), so every processor sees the symmetry in its data.

No absolute position enters, so predictions are translation invariant up to rounding.
Positions are centred on the particles' mean in float64 before the cast to float32, so the
limit is the precision of the input positions themselves (velocities are differences of
positions ~1e-4 m apart): with float32 positions the prediction moves by 4e-5 of its size for
an offset of 1 m but by 5e-3 at 10 m (float32 spacing 1e-6 m there); with float64 positions it
stays within 1e-6 up to 1e5 m. Tested: float32 at 1 m, float64 at 1 m and 1,000 m. Keep scenes
near the origin or pass float64 positions.

Integration is semi-implicit Euler with the module's step ``dt`` (s):
``v_{t+1} = v_t + dt a_t``, ``p_{t+1} = p_t + dt v_{t+1}``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

import torch
from torch import nn
from torch_geometric.data import Batch, Data

from granular_pyg.errors import InputError, NonFiniteError, check_coordinates_fit, check_tensor
from granular_pyg.geometry import canonical_frame, canonical_normals, horizontally_isotropic
from granular_pyg.nn import (
    EncodeProcessDecode,
    HorizontalEquivariantNetwork,
    HorizontalEquivariantProcessor,
    Processor,
)
from granular_pyg.progress import show_progress
from granular_pyg.scenes import Materials, WallSet
from granular_pyg.sleep import QUORUM, WAKE_ACCELERATION, at_rest, spread, supported
from granular_pyg.transforms import AddWallNodes, NeighbourList, RadiusGraph

__all__ = ["MATERIAL_FEATURES", "LearnedSimulator", "ParticleProps", "WallGuard"]


@dataclass
class WallGuard:
    """Keeps a rollout's particle centres inside the walls (:meth:`WallSet.contain`).

    A learned step that would carry a centre through a wall is cut at the wall, the centre
    left ``margin`` from it (an inelastic, frictionless contact). The model itself is unchanged:
    ``corrected`` counts how often the guard had to step in, so a guarded rollout still reports
    how far the network alone would leak.

    Attributes:
        margin: ``[N]`` float64 distance (m) a corrected centre keeps from the wall, one per
            particle of the rollout (usually its radius).
        corrected: particle-steps moved back so far.
    """

    margin: torch.Tensor
    corrected: int = 0


#: ``model.material_features``: each :class:`~granular_pyg.scenes.Materials` field the model
#: may take as an input column, and the fixed map that scales it to order one (so no statistics
#: are needed and a checkpoint's inputs never depend on its training data): friction,
#: restitution and Poisson's ratio as they are, rolling friction x 10, Young's modulus as
#: ``log10(E / 5e6 Pa)``, density / 2500 kg/m^3.
MATERIAL_FEATURES: dict[str, Callable[[float], float]] = {
    "friction": lambda v: v,
    "rolling_friction": lambda v: 10.0 * v,
    "restitution": lambda v: v,
    "youngs_modulus": lambda v: math.log10(v / 5.0e6),
    "poisson_ratio": lambda v: v,
    "density": lambda v: v / 2500.0,
}


@dataclass(frozen=True)
class ParticleProps:
    """What a model may know of the particles besides their positions: the inputs of the
    ``radius_feature`` and ``material_features`` options (see :class:`LearnedSimulator`).

    Row ``i`` belongs to row ``i`` of the ``pos_seq`` it goes with; ``props[mask]`` keeps the
    rows of a mask or index (the materials are the scene's, shared by all).

    Attributes:
        radius: ``[N]`` particle radii (m).
        materials: the Scene's :class:`~granular_pyg.scenes.Materials` (or a mapping of its
            fields), or None when unknown.
    """

    radius: torch.Tensor
    materials: Materials | Mapping | None = None

    def __post_init__(self) -> None:
        radius = torch.as_tensor(self.radius)
        if radius.dim() != 1 or not radius.is_floating_point():
            raise InputError(
                f"ParticleProps.radius: expected [N] float radii (m), got {radius.dtype} "
                f"{list(radius.shape)}"
            )
        object.__setattr__(self, "radius", radius)

    @classmethod
    def of(cls, trajectory) -> ParticleProps:
        """The radii and the Scene's materials of a :class:`~granular_pyg.io.Trajectory`."""
        scene = trajectory.scene
        return cls(
            torch.from_numpy(trajectory.radii), scene.materials if scene is not None else None
        )

    def __len__(self) -> int:
        return self.radius.shape[0]

    def __getitem__(self, rows) -> ParticleProps:
        """The rows ``rows`` (a bool mask, indices or a slice) of the particles."""
        if not isinstance(rows, slice):
            rows = torch.as_tensor(rows).to(self.radius.device)
        return ParticleProps(self.radius[rows], self.materials)

    def material(self, name: str) -> float:
        """The value of the Materials field ``name`` (SI units)."""
        if self.materials is None:
            raise InputError(
                f"model.material_features: {name!r} needs the scene's materials; this "
                "ParticleProps has none (build it with ParticleProps.of(trajectory) or "
                "ParticleProps(radii, scene.materials))"
            )
        m = self.materials
        value = m.get(name) if isinstance(m, Mapping) else getattr(m, name, None)
        if value is None or not math.isfinite(float(value)):
            raise InputError(f"materials.{name}: expected a finite value, got {value!r}")
        if name in ("youngs_modulus", "density") and not float(value) > 0:
            raise InputError(f"materials.{name}: expected a positive value, got {value!r}")
        return float(value)


NUM_DIMS = 3
NUM_TYPES = 2  # particle, wall
NUM_NORMAL_FEATURES = 6
NUM_EDGE_FEATURES = 4


#: Precisions of the network at inference: ``"32"`` (float32) or ``"bf16"`` (the matrix
#: products in bfloat16 under autocast, about 2x faster on CPUs with AVX-512 BF16; positions,
#: graphs, normalisation and integration stay float32 and float64).
NETWORK_PRECISIONS = ("32", "bf16")


class LearnedSimulator(nn.Module):
    """Encode-process-decode network over particles and virtual wall nodes.

    Args:
        processor: the message-passing processor (see ``conf/model/processor/``).
        radius: connectivity radius ``R`` for particle edges and wall nodes (m).
        history: number of past velocities ``H`` per particle (5 in the paper).
        normals: wall normal variant: ``"none"`` (V1), ``"single"`` (V2), ``"both"`` (V3).
        latent: latent width of encoder, processor and decoder.
        mlp_layers: hidden layers per MLP.
        wall_weight: weight a particle's ``k`` wall nodes by ``1/k`` (BGNN).
        dt: time step of one learned step (s): the frame spacing times ``frames_per_step``.
        graph_backend: radius-graph backend (``"auto"``, ``"scipy"``, ``"torch_cluster"``).
        max_num_neighbors: neighbour cap of the radius graph; None sizes it to fit.
        radius_feature: one more node input: a particle's radius / ``radius`` (0 on wall
            nodes), so one model can serve several particle sizes.
        material_features: more node inputs, one per named field of the Scene's Materials
            (keys of :data:`MATERIAL_FEATURES`, scaled by it), the same on every node.
        contact_feature: one more edge input: the edge's length over its contact distance
            (the two radii summed; a wall node's radius 0), 1 at contact for any particle size.
        wall_nodes: ``"triangle"`` (a wall node per nearby triangle, the paper's) or
            ``"patch"`` (per nearby surface patch, independent of the triangulation; see
            :class:`~granular_pyg.transforms.AddWallNodes`).
        walls_over_step: a step's graph holds the walls as they are over the step, from
            ``time`` to ``time + dt``: those there all through it, with their mean velocities over
            it (poses at ``time``). A lid removed or a drum started during the step shows in
            the inputs, which tell a bed that stays at rest from one that starts to move. With
            False (older models), the walls at ``time``: the two look alike, and the model
            learns their average, a bed that sinks through a closed lid or creeps in a drum at
            rest.
        sleep: particles that sleep (:mod:`granular_pyg.sleep`) get exactly zero
            acceleration outside training passes: those at rest in their history, resting on
            something, pushed by the network less than g/2, and beyond the model's reach of
            moving particles and of walls that move or change (:meth:`awake`). A bed at rest
            stays at rest to the bit; a flowing one is unchanged. No weights: any model can
            switch it on.
        canonical_frame: the network sees each scene in the scene's own horizontal frame
            (:func:`~granular_pyg.geometry.canonical_frame`: read off the walls' surface, their
            turning axis and, for ties, the particles: at a rollout's start, of each training
            window) and its prediction is turned back. A model that is not equivariant then
            gives the same flow for the scene turned about gravity or mirrored (re-meshed too,
            with ``wall_nodes="patch"``), as long as the frame is decided (not for an
            axisymmetric cone with a centred bed). No weights: any model can switch it on.

    With ``radius_feature``, ``contact_feature`` or ``material_features`` the graph needs a
    :class:`ParticleProps` (``props`` of :meth:`build_graph`, :meth:`step`,
    :meth:`rollout`); without them a model ignores it and is exactly the model without these
    options.
    """

    def __init__(
        self,
        processor: Processor | HorizontalEquivariantProcessor,
        radius: float,
        history: int = 5,
        normals: str = "both",
        latent: int = 128,
        mlp_layers: int = 2,
        wall_weight: bool = True,
        dt: float = 2.5e-3,
        graph_backend: str = "auto",
        max_num_neighbors: int | None = None,
        radius_feature: bool = False,
        material_features: Iterable[str] = (),
        contact_feature: bool = False,
        wall_nodes: str = "triangle",
        walls_over_step: bool = False,
        sleep: bool = False,
        canonical_frame: bool = False,
    ) -> None:
        super().__init__()
        if history < 1:
            raise InputError(f"history: need at least one past velocity, got {history}")
        if not dt > 0:
            raise InputError(f"dt: expected a positive time step (s), got {dt!r}")
        self.radius = float(radius)
        self.history = int(history)
        self.normals = normals
        if not isinstance(radius_feature, bool):
            raise InputError(
                f"model.radius_feature: expected true or false, got {radius_feature!r}"
            )
        if isinstance(material_features, str):
            material_features = [material_features]
        names = tuple(str(n) for n in (material_features or ()))
        unknown = [n for n in names if n not in MATERIAL_FEATURES]
        if unknown or len(set(names)) != len(names):
            raise InputError(
                f"model.material_features: expected distinct names among "
                f"{list(MATERIAL_FEATURES)}, got {list(names)}"
            )
        if not isinstance(contact_feature, bool):
            raise InputError(
                f"model.contact_feature: expected true or false, got {contact_feature!r}"
            )
        if not isinstance(walls_over_step, bool):
            raise InputError(
                f"model.walls_over_step: expected true or false, got {walls_over_step!r}"
            )
        self.walls_over_step = walls_over_step
        if not isinstance(sleep, bool):
            raise InputError(f"model.sleep: expected true or false, got {sleep!r}")
        self.sleep = sleep
        if not isinstance(canonical_frame, bool):
            raise InputError(
                f"model.canonical_frame: expected true or false, got {canonical_frame!r}"
            )
        self.canonical_frame = canonical_frame
        self.radius_feature, self.material_features = radius_feature, names
        self.contact_feature = contact_feature
        self.radius_graph = RadiusGraph(radius, graph_backend, max_num_neighbors)
        self.wall_nodes = AddWallNodes(radius, normals, wall_weight, wall_nodes)
        extra_in = int(self.radius_feature) + len(self.material_features)
        self.equivariant = isinstance(processor, HorizontalEquivariantProcessor)
        self.reach = self.radius * int(processor.num_steps)  # m: how far a step's news travels
        if self.equivariant:
            if processor.latent != latent:
                raise InputError(
                    f"processor: its latent width ({processor.latent}) differs from the "
                    f"model's ({latent}); the presets interpolate it as ${{..latent}}"
                )
            h = self.history
            node_in = h + h * (h + 1) // 2 + 2 + NUM_TYPES + extra_in
            edge_in = 4 + int(self.contact_feature)
            self.model = HorizontalEquivariantNetwork(
                node_in, h + 1, edge_in, processor, mlp_layers
            )
        else:
            node_in = NUM_DIMS * self.history + NUM_NORMAL_FEATURES + NUM_TYPES + extra_in
            edge_in = NUM_EDGE_FEATURES + int(self.contact_feature)
            self.model = EncodeProcessDecode(
                node_in,
                edge_in,
                NUM_DIMS,
                processor,
                latent=latent,
                mlp_layers=mlp_layers,
            )
        self.register_buffer("dt", torch.tensor(float(dt), dtype=torch.float64))
        self.network_dtype: torch.dtype | None = None  # None: float32 (see set_network_precision)
        self._compiled_network = None  # see compile_for_training (a function, not a submodule)
        for name, value in (
            ("vel_mean", 0.0),
            ("vel_std", 1.0),
            ("acc_mean", 0.0),
            ("acc_std", 1.0),
        ):
            self.register_buffer(name, torch.full((NUM_DIMS,), value))

    # -- normalisation ----------------------------------------------------------------------

    def set_normalization(
        self,
        vel_mean: torch.Tensor,
        vel_std: torch.Tensor,
        acc_mean: torch.Tensor,
        acc_std: torch.Tensor,
    ) -> None:
        """Set the statistics (``[3]`` each; m/s and m/s^2) kept in and saved with the module.

        An equivariant model keeps them isotropic in the horizontal plane (what a turn about
        gravity or a mirror leaves unchanged): the horizontal means become 0 and the two
        horizontal stds their root mean square with the means, ``sqrt(mean_xy(std^2 +
        mean^2))`` (:func:`~granular_pyg.geometry.horizontally_isotropic`)."""
        if self.equivariant:
            vel_mean, vel_std = horizontally_isotropic(vel_mean, vel_std)
            acc_mean, acc_std = horizontally_isotropic(acc_mean, acc_std)
        for name, value in (
            ("vel_mean", vel_mean),
            ("vel_std", vel_std),
            ("acc_mean", acc_mean),
            ("acc_std", acc_std),
        ):
            value = torch.as_tensor(value, dtype=torch.float32).reshape(NUM_DIMS)
            if not bool(torch.isfinite(value).all()) or (
                name.endswith("std") and (value <= 0).any()
            ):
                raise InputError(f"{name}: expected finite values (std > 0), got {value.tolist()}")
            getattr(self, name).copy_(value)

    def velocities(self, pos_seq: torch.Tensor) -> torch.Tensor:
        """``[N, H, 3]`` finite-difference velocities (m/s, float64) of ``pos_seq [N, H+1, 3]``."""
        return torch.diff(pos_seq.double(), dim=1) / self.dt

    def integrate(self, pos_seq: torch.Tensor, acc: torch.Tensor) -> torch.Tensor:
        """Next positions ``[N, 3]`` (m, float64) after one step ``dt`` of semi-implicit Euler
        from ``pos_seq [N, H + 1, 3]`` (m) with accelerations ``acc [N, 3]`` (m/s^2); the
        inverse of :meth:`target_acceleration` (before its normalisation). Differentiable."""
        next_vel = self.velocities(pos_seq[:, -2:])[:, 0] + self.dt * acc.double()
        return pos_seq[:, -1].double() + self.dt * next_vel

    def target_acceleration(
        self,
        pos_seq: torch.Tensor,
        target_pos: torch.Tensor,
        frame: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Normalised acceleration ``[N, 3]`` that takes the last state to ``target_pos``,
        expressed in ``frame`` (``[3, 3]`` orthogonal, see :meth:`build_graph`) if given."""
        pos_seq, target_pos = pos_seq.to(self.dt.device), target_pos.to(self.dt.device)
        last_vel = self.velocities(pos_seq[:, -2:])[:, 0]
        next_vel = (target_pos.double() - pos_seq[:, -1].double()) / self.dt
        acc = (next_vel - last_vel) / self.dt
        if frame is not None:
            acc = acc @ frame.to(acc).T
        return ((acc - self.acc_mean.double()) / self.acc_std.double()).float()

    # -- graph and features -----------------------------------------------------------------

    @property
    def uses_props(self) -> bool:
        """Whether the features need a :class:`ParticleProps` (radius, contact or material
        inputs)."""
        return self.radius_feature or self.contact_feature or bool(self.material_features)

    def _check_props(self, props: ParticleProps | None, num: int) -> None:
        """Refuse a missing or mis-sized ``props`` when the options need it (no-op otherwise)."""
        if not self.uses_props:
            return
        if props is None:
            options = [
                f"model.{name}=true"
                for name in ("radius_feature", "contact_feature")
                if getattr(self, name)
            ]
            if self.material_features:
                options.append(f"model.material_features={list(self.material_features)}")
            raise InputError(
                f"props: this model was built with {' and '.join(options)}, so its features "
                "need the particles' radii and the scene's materials; pass "
                "props=ParticleProps.of(trajectory) (or ParticleProps(radii, scene.materials)) "
                "with one row per row of pos_seq"
            )
        if not isinstance(props, ParticleProps):
            raise InputError(f"props: expected a ParticleProps, got {type(props).__name__}")
        if len(props) != num:
            raise InputError(
                f"props: {len(props)} radii for {num} particles; give one per row of pos_seq"
            )
        if self.radius_feature or self.contact_feature:
            radius = props.radius
            if not bool((torch.isfinite(radius) & (radius > 0)).all()):
                raise InputError("props.radius: every radius must be finite and positive (m)")

    def build_graph(
        self,
        pos_seq: torch.Tensor,
        walls: WallSet,
        time: float,
        neighbours: NeighbourList | None = None,
        ids: torch.Tensor | None = None,
        props: ParticleProps | None = None,
        frame: torch.Tensor | None = None,
    ) -> Data:
        """The input graph for one state.

        Args:
            pos_seq: ``[N, H + 1, 3]`` positions of the present particles at the last ``H + 1``
                steps (m, world frame), oldest first; float32 or float64.
            walls: the scene's walls.
            time: recorded time (s) of the last position (sets wall poses; which walls exist
                and their velocities too, or the step to ``time + dt`` with ``walls_over_step``).
            neighbours: a :class:`NeighbourList` to reuse over a rollout (same edges as a
                fresh radius graph); None: a fresh radius graph.
            ids: ``[N]`` increasing ids of the present particles, for ``neighbours``.
            props: the ``N`` particles' :class:`ParticleProps` (their rows of it); needed with
                ``radius_feature`` or ``material_features`` (InputError without), else ignored.
            frame: ``[3, 3]`` orthogonal matrix fixing the z axis (a turn about gravity, maybe
                with a mirror): the features are those of the scene turned by it; None: the
                identity. The graph itself (edges, wall nodes) is the same in every frame.

        The edges and the walls' closest points come from detached positions; the features
        (velocities, displacements) keep ``pos_seq``'s gradient, if it has one.

        Returns:
            A Data with ``x [N + W, 3H + 8 + P]`` (``P`` property columns, 0 by default),
            ``edge_index [2, E]``, ``edge_attr [E, 4]`` (5 with ``contact_feature``),
            ``is_wall [N + W]`` and ``num_real = N``, ready to batch; with the equivariant
            processor the inputs of :meth:`_equivariant_features` instead.
        """
        check_tensor("pos_seq", pos_seq, (None, self.history + 1, NUM_DIMS))
        self._check_props(props, pos_seq.shape[0])
        # The geometry (edges, walls' closest points) on the CPU, where the walls live; the
        # features on the model's device, from pos_seq there (its gradient kept).
        device = self.dt.device
        pos_seq = pos_seq.to(device)
        last = pos_seq[:, -1]
        data = Data(pos=last.detach().cpu(), walls=walls, time=float(time))
        if self.walls_over_step:
            data.step_end = float(time) + float(self.dt)
        if neighbours is None:
            data = self.radius_graph(data)
        else:
            data.edge_index = neighbours(data.pos, ids.cpu() if ids is not None else None)
        data = self.wall_nodes(data).to(device)
        if last.requires_grad:  # unrolled training: the features keep the positions' gradient
            data.pos = torch.cat([last.to(data.pos.dtype), data.pos[data.num_real :]])
        if self.equivariant:
            return self._equivariant_features(data, pos_seq, props, frame)
        return self._features(data, pos_seq, props, frame)

    def _vectors_in_frame(
        self, data: Data, pos_seq: torch.Tensor, frame: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The vector inputs in ``frame``: positions relative to the particles' mean
        ``[N + W, 3]`` (float64 first: translation invariance), normalised velocities
        ``[N, H, 3]`` and wall velocities ``[W, 3]``, and the wall normal the variant sees
        ``[N + W, 3]`` (V2: the winding's; V3: the canonical one; V1: zeros), all float32."""
        num_real = data.num_real
        centre = data.pos[:num_real].double().mean(dim=0)
        rel = data.pos.double() - centre
        vel = self.velocities(pos_seq)
        wall_vel = data.wall_vel[num_real:].double()
        normal = data.normal_feat[:, :3].double()
        if frame is not None:
            q = frame.to(rel.device, torch.float64).T
            rel, vel, wall_vel, normal = rel @ q, vel @ q, wall_vel @ q, normal @ q
        dtype = self.vel_mean.dtype  # float32, or float64 for a model turned to double
        vel = (vel.to(dtype) - self.vel_mean) / self.vel_std
        wall_vel = (wall_vel.to(dtype) - self.vel_mean) / self.vel_std
        return rel.to(dtype), vel, wall_vel, normal.to(dtype)

    def _normal_features(self, normal: torch.Tensor, data: Data) -> torch.Tensor:
        """The variant's six normal columns ``[N + W, 6]`` of the (possibly turned) normal."""
        if self.wall_nodes.normals == "single":
            return torch.cat([normal, torch.zeros_like(normal)], dim=1)
        if self.wall_nodes.normals == "both":
            feat = canonical_normals(normal)
            return torch.where(data.is_wall.unsqueeze(1), feat, torch.zeros_like(feat))
        return normal.new_zeros((normal.shape[0], NUM_NORMAL_FEATURES))

    def _features(
        self,
        data: Data,
        pos_seq: torch.Tensor,
        props: ParticleProps | None = None,
        frame: torch.Tensor | None = None,
    ) -> Data:
        num_real = data.num_real
        if frame is None:  # the features exactly as the shipped models were trained on
            centre = data.pos[:num_real].double().mean(dim=0)
            rel = (data.pos.double() - centre).float()  # float64 first: translation invariance
            vel = (self.velocities(pos_seq).float() - self.vel_mean) / self.vel_std
            wall_vel = (data.wall_vel[num_real:].float() - self.vel_mean) / self.vel_std
            normal_feat = data.normal_feat.float()
        else:
            rel, vel, wall_vel, normal = self._vectors_in_frame(data, pos_seq, frame)
            normal_feat = self._normal_features(normal, data)
        vel_feat = torch.cat([vel.flatten(1), wall_vel.repeat(1, self.history)])
        kind = torch.nn.functional.one_hot(data.is_wall.long(), NUM_TYPES).float()
        x = torch.cat([vel_feat, normal_feat, kind], dim=1)
        x = x * data.node_weight.float().unsqueeze(1)
        # node property columns after the wall weight: the values themselves on every node
        x = self._with_property_columns(x, props, num_real)
        src, dst = data.edge_index
        disp = (rel[dst] - rel[src]) / self.radius
        edge_attr = torch.cat([disp, torch.linalg.vector_norm(disp, dim=1, keepdim=True)], 1)
        if self.contact_feature:
            edge_attr = torch.cat([edge_attr, self._contact_column(edge_attr, src, dst, props)], 1)
        dtype = self.vel_mean.dtype  # float32 (a no-op), or float64 for a model turned to double
        return Data(
            x=x.to(dtype),
            edge_index=data.edge_index,
            edge_attr=edge_attr.to(dtype),
            is_wall=data.is_wall,
            num_real=num_real,
            pos=data.pos,
        )

    def _equivariant_features(
        self,
        data: Data,
        pos_seq: torch.Tensor,
        props: ParticleProps | None = None,
        frame: torch.Tensor | None = None,
    ) -> Data:
        """Scalars and horizontal vectors for the equivariant network.

        Node scalars ``x [N + W, H + H (H + 1) / 2 + 2 + 2 + P]``: the vertical velocities, the
        Gram matrix of the horizontal velocities (upper triangle), two normal invariants (V1:
        zeros; V2: ``n_z, |n_h|``; V3: ``|n_z|, |n_h|``, the same for either orientation), the
        type one-hot, then the property columns. Node vectors ``vec [N + W, H + 1, 2]``: the
        horizontal velocities and the normal's horizontal part (V2: ``n_h``; V3: ``n_z n_h``,
        even in the orientation; V1: zeros). A wall node's velocities are the wall's, and its
        scalars and vectors are weighted like the other models' features. Edge scalars
        ``edge_attr [E, 4 (+1)]``: ``|d_h|, d_z, |d|`` of ``d = (x_i - x_j) / R`` and the
        sender's normal along ``d`` (V2: ``n . d``; V3: ``|n . d|``; V1: 0), then the contact
        column; edge vectors ``edge_vec [E, 2] = d_h``.
        """
        num_real, h = data.num_real, self.history
        rel, vel, wall_vel, normal = self._vectors_in_frame(data, pos_seq, frame)
        vel_all = torch.cat([vel, wall_vel.unsqueeze(1).expand(-1, h, -1)])  # [N + W, H, 3]
        horiz = vel_all[..., :2]
        rows, cols = torch.triu_indices(h, h)
        gram = (horiz[:, rows] * horiz[:, cols]).sum(dim=-1)  # [N + W, H (H + 1) / 2]
        n_h, n_z = normal[:, :2], normal[:, 2:]
        n_h_len = torch.linalg.vector_norm(n_h, dim=1, keepdim=True)
        variant = self.wall_nodes.normals
        if variant == "single":
            normal_scalars, normal_vec = torch.cat([n_z, n_h_len], 1), n_h
        elif variant == "both":
            normal_scalars, normal_vec = torch.cat([n_z.abs(), n_h_len], 1), n_z * n_h
        else:
            normal_scalars, normal_vec = n_h.new_zeros((n_h.shape[0], 2)), torch.zeros_like(n_h)
        kind = torch.nn.functional.one_hot(data.is_wall.long(), NUM_TYPES).to(rel.dtype)
        weight = data.node_weight.to(rel.dtype).unsqueeze(1)
        x = torch.cat([vel_all[..., 2], gram, normal_scalars, kind], 1) * weight
        vec = torch.cat([horiz, normal_vec.unsqueeze(1)], dim=1) * weight.unsqueeze(-1)
        x = self._with_property_columns(x, props, num_real)
        src, dst = data.edge_index
        disp = (rel[dst] - rel[src]) / self.radius
        along = (normal[src] * disp).sum(dim=1, keepdim=True)
        if variant == "both":
            along = along.abs()
        elif variant == "none":
            along = torch.zeros_like(along)
        length = torch.linalg.vector_norm(disp, dim=1, keepdim=True)
        edge_attr = torch.cat(
            [
                torch.linalg.vector_norm(disp[:, :2], dim=1, keepdim=True),
                disp[:, 2:],
                length,
                along,
            ],
            dim=1,
        )
        if self.contact_feature:
            edge_attr = torch.cat([edge_attr, self._contact_column(length, src, dst, props)], 1)
        return Data(
            x=x,
            vec=vec,
            edge_index=data.edge_index,
            edge_attr=edge_attr,
            edge_vec=disp[:, :2].contiguous(),
            is_wall=data.is_wall,
            num_real=num_real,
            pos=data.pos,
        )

    def _contact_column(
        self, edge_attr: torch.Tensor, src: torch.Tensor, dst: torch.Tensor, props: ParticleProps
    ) -> torch.Tensor:
        """``[E, 1]``: each edge's length over its contact distance ``r_i + r_j`` (a wall
        node's ``r`` is 0; every edge ends at a particle, so the sum is positive). The edge's
        length over ``R`` is ``edge_attr[:, 3]``, or ``edge_attr[:, 0]`` for a one-column
        ``edge_attr``."""
        radius = props.radius.to(edge_attr.device, edge_attr.dtype)
        num_real = radius.shape[0]
        sender = torch.where(src < num_real, radius[src.clamp(max=num_real - 1)], 0.0)
        contact = (sender + radius[dst]) / self.radius  # in the cut-off's units, like the length
        length = edge_attr if edge_attr.shape[1] == 1 else edge_attr[:, 3:4]
        return length / contact.unsqueeze(1)

    def _with_property_columns(
        self, x: torch.Tensor, props: ParticleProps | None, num_real: int
    ) -> torch.Tensor:
        """``x [N + W, F]`` with the ``P`` property columns appended, ``[N + W, F + P]``
        (``x`` itself for a model without radius or material inputs)."""
        if not (self.radius_feature or self.material_features):
            return x
        num_wall = x.shape[0] - num_real
        return torch.cat([x, self._property_columns(props, num_wall, x)], dim=1)

    def _property_columns(
        self, props: ParticleProps, num_wall: int, like: torch.Tensor
    ) -> torch.Tensor:
        """``[N + W, P]``: radius / R (wall nodes 0), then each material input."""
        num = len(props) + num_wall
        cols = []
        if self.radius_feature:
            radius = props.radius.to(like.device, torch.float64) / self.radius
            cols.append(torch.cat([radius.to(like.dtype), like.new_zeros(num_wall)]))
        for name in self.material_features:
            cols.append(like.new_full((num,), MATERIAL_FEATURES[name](props.material(name))))
        return torch.stack(cols, dim=1)

    # -- prediction and integration -----------------------------------------------------------

    def set_network_precision(self, precision: str) -> None:
        """Run the network in ``precision`` (one of :data:`NETWORK_PRECISIONS`) from now on."""
        if precision not in NETWORK_PRECISIONS:
            raise InputError(
                f"precision: expected one of {list(NETWORK_PRECISIONS)}, got {precision!r}"
            )
        self.network_dtype = torch.bfloat16 if precision == "bf16" else None

    def compile_for_training(self) -> None:
        """Run the network through ``torch.compile`` (dynamic shapes) whenever autograd is
        recording, i.e. in training steps; validation and rollouts stay eager (their blocked
        loops would recompile for every edge count). The weights and the ``state_dict`` are
        the model's own. Under bf16 autocast on a CPU the fused kernels make a training step
        about 1.3x faster (float32: no gain); the first steps pay the compilation, about a
        minute on two cores (cached on disk for the next run)."""
        self._compiled_network = torch.compile(self.model.forward, dynamic=True)

    def forward(self, graph: Data | Batch) -> torch.Tensor:
        """Normalised acceleration ``[num real particles, 3]`` (float32) of a graph or a batch
        of graphs (every particle's: sleeping acts in :meth:`predict_acceleration`)."""
        return self._network_output(graph)

    def awake(
        self,
        pos_seq: torch.Tensor,
        graph: Data,
        walls: WallSet,
        time: float,
        acceleration: torch.Tensor,
    ) -> torch.Tensor:
        """``[N]`` bool: the particles of ``pos_seq [N, H + 1, 3]`` (m) that are awake
        (:mod:`granular_pyg.sleep`) for the learned step from ``time`` (s) over ``graph``
        (their graph, with node positions ``pos``), given the network's ``acceleration
        [N, 3]`` (m/s^2): moved in their history, given more than ``WAKE_ACCELERATION``, or
        with no node of the graph beneath them (nothing to rest on), or reached over
        ``num_steps`` hops of ``QUORUM`` such neighbours, or within ``reach`` of a wall that
        moves or changes in the step."""
        real = ~graph.is_wall
        seeds = ~supported(graph.pos, graph.edge_index)
        pushed = torch.linalg.vector_norm(acceleration, dim=1) > WAKE_ACCELERATION
        moving = ~at_rest(pos_seq, float(self.dt))
        seeds[real] |= moving | pushed
        hops = int(self.model.processor.num_steps)
        awake = spread(seeds, graph.edge_index, graph.is_wall, hops, QUORUM)[real]
        if not bool(awake.all()):
            woken = self.woken_by_walls(pos_seq[:, -1], walls, time)
            if woken is not None:
                awake |= woken
        return awake

    def woken_by_walls(
        self, points: torch.Tensor, walls: WallSet, time: float
    ) -> torch.Tensor | None:
        """``[N]`` bool: the particles at ``points [N, 3]`` (m) within the model's ``reach``
        of a wall that moves within the learned step from ``time`` (s), or that changes in it
        (removed; its motion started, stopped or reversed), or None without such a wall. A wall
        removed at the step's very end is still there for the step (:meth:`WallSet.contacts`)
        and wakes nothing."""
        end = time + float(self.dt) - 1e-6
        changed = sorted(set(walls.changing(time, end)) | set(walls.moving(time, end)))
        if not changed:
            return None
        return walls.near(points, self.reach, time, changed).to(points.device)

    def scene_frame(self, walls: WallSet, points: torch.Tensor) -> torch.Tensor | None:
        """The frame ``[3, 3]`` (float64) the network sees ``walls`` in, with ``points [N, 3]``
        (m, NaN rows ignored) to break the walls' ties: the scene's own
        (:func:`~granular_pyg.geometry.canonical_frame`) with ``canonical_frame``, else None
        (the world frame)."""
        if not self.canonical_frame:
            return None
        points = points.detach().double().cpu()
        points = points[torch.isfinite(points).all(dim=1)].numpy()
        return torch.from_numpy(canonical_frame(walls.walls, points))

    def _network_output(self, graph: Data | Batch) -> torch.Tensor:
        """The network's output rows of the real particles: ``[N, 3]`` normalised
        acceleration."""
        compiled = self._compiled_network is not None and torch.is_grad_enabled()
        network = self._compiled_network if compiled else self.model
        if self.equivariant:
            # the edges from wall nodes, only for a processor that sums their messages
            wall_sum = self.model.processor.wall_sum
            from_wall = graph.is_wall[graph.edge_index[0]] if wall_sum else None
            inputs = (graph.x, graph.vec, graph.edge_index, graph.edge_attr, graph.edge_vec)
            inputs += (from_wall,)
        else:
            inputs = (graph.x, graph.edge_index, graph.edge_attr)
        if self.network_dtype is None:
            out = network(*inputs)
        else:
            with torch.autocast(graph.x.device.type, dtype=self.network_dtype):
                out = network(*inputs)
            out = out.float()
        return out[~graph.is_wall]

    def predict_acceleration(
        self,
        pos_seq: torch.Tensor,
        walls: WallSet,
        time: float,
        neighbours: NeighbourList | None = None,
        ids: torch.Tensor | None = None,
        props: ParticleProps | None = None,
        frame: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Physical acceleration ``[N, 3]`` (m/s^2, float32) of the present particles, in the
        world frame (the arguments are :meth:`build_graph`'s; with a ``frame`` the network
        sees the turned scene and its prediction is turned back)."""
        graph = self.build_graph(pos_seq, walls, time, neighbours, ids, props, frame)
        out = self._network_output(graph)
        acc = out * self.acc_std + self.acc_mean
        if self.sleep and not (self.training and torch.is_grad_enabled()):
            acc = acc * self.awake(pos_seq, graph, walls, time, acc)[:, None]
        if frame is not None:
            acc = acc @ frame.to(acc)
        return acc

    @torch.no_grad()
    def step(
        self,
        pos_seq: torch.Tensor,
        walls: WallSet,
        time: float,
        outflow_z: float | None = None,
        neighbours: NeighbourList | None = None,
        guard: WallGuard | None = None,
        props: ParticleProps | None = None,
        frame: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Advance one learned step (``dt``).

        Particles with any NaN in ``pos_seq`` have left: they are masked out and stay NaN. With
        a ``guard``, moves through a wall end at the wall. A particle whose new centre then lies
        below ``outflow_z`` (m) leaves (becomes NaN).

        Args:
            pos_seq: ``[N, H + 1, 3]`` positions (m), NaN rows for particles that have left.
            walls: the scene's walls.
            time: recorded time (s) of the last position.
            outflow_z: the scene's outflow height (m), or None.
            neighbours: a :class:`NeighbourList` kept over the steps of a rollout, or None.
            guard: a :class:`WallGuard` over the ``N`` particles, or None.
            props: :class:`ParticleProps` of the ``N`` particles (all rows, sliced here like
                ``pos_seq``); needed by a model with radius or material inputs.
            frame: the ``[3, 3]`` frame the network sees the scene in (:meth:`rollout` fixes
                :meth:`scene_frame` at its start); None: :meth:`scene_frame` of this state.

        Returns:
            ``[N, 3]`` next positions in the dtype of ``pos_seq``.
        """
        check_tensor("pos_seq", pos_seq, (None, self.history + 1, NUM_DIMS), finite=False)
        self._check_props(props, pos_seq.shape[0])
        present = torch.isfinite(pos_seq).all(dim=2).all(dim=1)
        out = torch.full_like(pos_seq[:, -1], float("nan"))
        if not bool(present.any()):
            return out
        nan = torch.isnan(pos_seq)
        gone = nan.all(dim=2)  # [N, H + 1]: positions of a particle that has left
        invalid = (
            (nan.any(dim=2) & ~gone).any(dim=1)  # some coordinates NaN, not all
            | (gone[:, :-1] & ~gone[:, 1:]).any(dim=1)  # back after leaving
            | torch.isinf(pos_seq).any(dim=2).any(dim=1)
        )
        if bool(invalid.any()):
            rows = invalid.nonzero()[:, 0]
            raise InputError(
                f"pos_seq: {len(rows)} particle(s) with Inf, NaN in only some coordinates, "
                f"or finite after NaN: rows {rows[:10].tolist()}; a particle that has left "
                "is NaN in every coordinate from then on, and Inf is never allowed"
            )
        seq = pos_seq[present]
        check_coordinates_fit("pos_seq", seq, self.radius_graph.radius)
        ids = present.nonzero().squeeze(1) if neighbours is not None else None
        sub = props[present] if props is not None else None
        if frame is None:
            frame = self.scene_frame(walls, seq[:, -1])
        acc = self.predict_acceleration(seq, walls, time, neighbours, ids, sub, frame).double()
        finite = torch.isfinite(acc).all(dim=1)
        if not bool(finite.all()):
            bad = present.nonzero()[:, 0][~finite].tolist()
            raise NonFiniteError(
                f"the model predicted NaN/Inf accelerations at t = {time:g} s for "
                f"{len(bad)} particle(s), rows {bad[:10]}; the rollout stops here (its "
                "predictions so far are kept). Check the checkpoint's training, or roll out "
                "with dtype=float64",
                bad,
            )
        nxt = self.integrate(seq, acc)
        if guard is not None:
            if guard.margin.shape != present.shape:
                raise InputError(
                    f"guard.margin: expected one distance per particle, shape "
                    f"[{present.shape[0]}], got {list(guard.margin.shape)}"
                )
            end_time = time + float(self.dt)
            margin = guard.margin[present]
            nxt, corrected = walls.contain(
                seq[:, -1], nxt, time, end_time, margin, self.radius_graph.radius
            )
            guard.corrected += corrected
        out[present] = nxt.to(pos_seq.dtype)
        if outflow_z is not None:
            out[out[:, 2] < outflow_z] = float("nan")
        return out

    @torch.no_grad()
    def rollout(
        self,
        pos_seq: torch.Tensor,
        walls: WallSet,
        time: float,
        steps: int,
        outflow_z: float | None = None,
        progress: bool = False,
        skin: float | None = None,
        guard: WallGuard | None = None,
        on_step: Callable[[int, float, torch.Tensor, torch.Tensor], bool | None] | None = None,
        keep: bool = True,
        props: ParticleProps | None = None,
    ) -> torch.Tensor:
        """Autoregressive rollout of ``steps`` learned steps from ``pos_seq``: the one loop that
        ``rollout``, ``evaluate`` and ``stress`` run.

        Args:
            pos_seq: ``[N, H + 1, 3]`` initial positions (m), NaN rows for absent particles.
            walls: the scene's walls (posed at each step's time).
            time: recorded time (s) of the last initial position.
            steps: learned steps to take.
            outflow_z: the scene's outflow height (m), or None.
            progress: show a progress bar (in a terminal).
            skin: reuse the radius graph between steps with this Verlet skin (m); the same
                edges as fresh graphs, fewer tree searches. None: a fresh graph every step.
            guard: keep centres inside the walls (:class:`WallGuard`); None: the model alone.
            on_step: a per-step check, ``on_step(s, t, seq, nxt)`` with the step index, its
                start time (s), the ``[N, H + 1, 3]`` input and the ``[N, 3]`` prediction
                before the outflow removes anyone. It may set rows of ``nxt`` to NaN (particles
                that left) and returns True to end the rollout after this step.
            keep: return the predictions; False returns an empty ``[0, N, 3]`` (long checks).
            props: :class:`ParticleProps` of the ``N`` particles, for a model with radius or
                material inputs (each step keeps the rows of the particles still present).

        Returns:
            ``[S, N, 3]`` predicted positions, NaN for particles that have left; ``S = steps``
            unless ``on_step`` ended the rollout earlier.
        """
        from tqdm.auto import tqdm

        seq, out = pos_seq, []
        dt = float(self.dt)
        rg = self.radius_graph
        neighbours = None if skin is None else NeighbourList(rg.radius, skin, rg.backend)
        bar = tqdm(range(steps), desc="rollout", unit="step", disable=not show_progress(progress))
        frame = self.scene_frame(walls, pos_seq[:, -1])  # fixed: the start decides any tie
        for s in bar:
            t = time + s * dt
            try:
                nxt = self.step(seq, walls, t, None, neighbours, guard, props, frame)
                stop = bool(on_step(s, t, seq, nxt)) if on_step is not None else False
            except NonFiniteError as exc:
                exc.step = s
                exc.args = (f"learned step {s}: {exc.args[0]}",)
                exc.positions_so_far = (
                    torch.stack(out) if out else pos_seq.new_zeros((0, *pos_seq.shape[::2]))
                )
                raise
            if outflow_z is not None:
                nxt[nxt[:, 2] < outflow_z] = float("nan")
            if keep:
                out.append(nxt)
            seq = torch.cat([seq[:, 1:], nxt[:, None]], dim=1)
            if stop:
                break
        return torch.stack(out) if out else pos_seq.new_zeros((0, *pos_seq.shape[::2]))
