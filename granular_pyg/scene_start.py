"""A learned rollout's start from a Scene alone, without any DEM frame.

The particles are placed without overlap in the Scene's insertion region
(:func:`granular_pyg.scenes.packing.pack_particles`, as LIGGGHTS's ``insert/pack``), or in the
walls' interior below the box's top when the region is too small for the bed, at rest,
at the start of the fill: recorded time ``-settle_time`` (``t = 0`` is where LIGGGHTS starts
recording, after its fill and settle). A model rolled out from there fills, settles, opens the
outlet (the lid's removal time) and discharges on its own: the whole job, network alone.

``python -m granular_pyg.rollout ckpt=pretrained:hopper scene=hopper`` (no ``trajectory=``)
starts here.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from granular_pyg import inference, metrics
from granular_pyg.errors import InputError
from granular_pyg.io import Trajectory
from granular_pyg.scenes import ParticleSpec, Scene
from granular_pyg.scenes.containment import inside_convex_hull, is_closed_surface, walls_at
from granular_pyg.scenes.packing import MAX_FRACTION, pack_particles, region_base_area

__all__ = [
    "BY_INDEX_SCALARS",
    "recorded_part",
    "scene_start",
    "start_from_scene_config",
    "whole_job_scalars",
    "whole_job_steps",
]


def scene_start(
    scene: Scene,
    history: int,
    frames_per_step: int = 1,
    seed: int = 0,
    max_fraction: float = MAX_FRACTION,
) -> Trajectory:
    """The initial states of a rollout from ``scene`` alone: ``history * frames_per_step + 1``
    frames ``scene.frame_dt`` apart from recorded time ``-scene.settle_time``, every one the
    same packing at rest (zero velocities), so the learned history says "at rest".

    Args:
        scene: the Scene (walls, insertion region, times).
        history: the model's history ``H`` (its velocities need ``H + 1`` positions).
        frames_per_step: saved frames per learned step ``k`` (the model's ``dt / frame_dt``).
        seed: the packing's seed.
        max_fraction: solid fraction of the region above which its top rises
            (:func:`~granular_pyg.scenes.packing.pack_particles`).

    Returns:
        A Trajectory with the Scene; metadata ``start: "scene"``, the seed and the region used.
    """
    if history < 1 or frames_per_step < 1:
        raise InputError(
            f"history ({history}) and frames_per_step ({frames_per_step}) must be at least 1"
        )
    spec, inside = _packing_room(scene, max_fraction)
    packing = pack_particles(
        spec,
        seed=seed,
        max_fraction=max_fraction,
        ceiling=_box_top(scene, spec),
        inside=inside,
    )
    frames = history * frames_per_step + 1
    times = -float(scene.settle_time) + float(scene.frame_dt) * np.arange(frames)
    positions = np.broadcast_to(packing.positions, (frames, *packing.positions.shape))
    return Trajectory(
        positions=positions.astype(np.float32),
        velocities=np.zeros((frames, *packing.positions.shape), np.float32),
        radii=packing.radii.astype(np.float32),
        ids=np.arange(1, len(packing.radii) + 1, dtype=np.int64),
        times=times,
        scene=scene,
        metadata={
            "start": "scene",
            "packing_seed": int(seed),
            "packing_region_lo": packing.region_lo.tolist(),
            "packing_region_hi": packing.region_hi.tolist(),
            "packing_fraction": float(packing.fraction),
        },
    )


def _box_top(scene: Scene, spec: ParticleSpec) -> float:
    """The highest a packed particle's top may reach (m): the simulation box's top, less the
    largest radius (a particle above the box has left the scene)."""
    return float(scene.domain_hi[2]) - float(np.max(spec.size_distribution[0]))


def _packing_room(scene: Scene, max_fraction: float):
    """``(spec, inside)`` for :func:`pack_particles`: the Scene's own insertion region when it
    holds the bed at ``max_fraction`` below the box's top; else, like LIGGGHTS's successive
    insertions stacking the bed up inside the equipment, the walls' interior (their convex
    hull, each whole particle in it) from the region's bottom to the box's top, the region's
    bounding box widened to the walls' and ``inside`` the hull test. Closed walls (a drum) or
    walls that enclose no volume keep the region (it then rises as far as the box allows)."""
    spec = scene.particles
    radii = np.asarray(spec.size_distribution[0], np.float64)
    weights = np.asarray(spec.size_distribution[1], np.float64)
    mean_volume = float((4.0 / 3.0 * np.pi * radii**3 * weights).sum() / weights.sum())
    lo = np.asarray(spec.fill_lo, np.float64)
    top = _box_top(scene, spec)
    if lo[2] + spec.count * mean_volume / max_fraction / region_base_area(spec) <= top:
        return spec, None
    triangles, _ = walls_at(scene, -float(scene.settle_time))
    if not len(triangles) or is_closed_surface(triangles):
        return spec, None
    try:
        hull = ConvexHull(triangles.reshape(-1, 3))
    except QhullError:  # flat walls: no interior
        return spec, None
    box_lo = np.maximum(hull.min_bound, scene.domain_lo)
    box_hi = np.minimum(hull.max_bound, scene.domain_hi)
    room = dataclasses.replace(
        spec,
        fill_lo=(float(box_lo[0]), float(box_lo[1]), float(lo[2])),
        fill_hi=(float(box_hi[0]), float(box_hi[1]), top),
        fill_shape="box",
    )

    return room, lambda centres, r: inside_convex_hull(centres, hull, tol=r)


def whole_job_steps(scene: Scene, history: int, frames_per_step: int) -> int:
    """Learned steps from :func:`scene_start`'s last initial state to the end of the Scene's
    recorded time (fill + settle + the recorded ``duration``)."""
    dt = frames_per_step * float(scene.frame_dt)
    total = float(scene.settle_time) + float(scene.duration)
    return max(1, round(total / dt) - history)


def start_from_scene_config(scene_cfg, sim, seed: int = 0, steps: int | None = None):
    """``(start, steps)`` for ``rollout`` / ``evaluate`` given ``scene=<name or file>`` and no
    trajectory: the Scene built from its config (``scene.build``), :func:`scene_start` for the
    model ``sim`` (its history and step), and ``steps`` or, when None, the whole job
    (:func:`whole_job_steps`)."""
    import hydra
    from omegaconf import OmegaConf

    from granular_pyg.errors import whole_number
    from granular_pyg.inference import frames_per_step

    build = OmegaConf.to_container(scene_cfg.build, resolve=True)
    scene = hydra.utils.instantiate(build, _convert_="all")
    k = frames_per_step(sim, float(scene.frame_dt))
    start = scene_start(scene, sim.history, k, seed=whole_number("seed", seed))
    if steps is None:
        return start, whole_job_steps(scene, sim.history, k)
    return start, whole_number("steps", steps)


#: Scalars that pair particles by index: meaningless where the rollout's particles were packed
#: anew (NaN in an evaluation from the scene alone).
BY_INDEX_SCALARS = ("position_mse", "mixing_entropy_error")


def recorded_part(pred: Trajectory, truth: Trajectory) -> Trajectory:
    """The frames of a rollout from the scene alone at the recorded times of ``truth``
    (``t >= truth.times[0]``), their times set to ``truth``'s, as a rollout with one initial
    frame (metadata ``initial_frames = 1``), for :func:`granular_pyg.evaluation.evaluate_pair`.

    Raises:
        InputError: the rollout does not reach the recorded times, or its frames do not fall
            on ``truth``'s frames (a learned step that does not divide the settle time).
    """
    keep = pred.times >= truth.times[0] - 1e-6 * truth.frame_dt
    keep &= pred.times <= truth.times[-1] + 1e-6 * truth.frame_dt
    if keep.sum() < 2:
        raise InputError(
            "from_scene: the rollout from the scene alone does not reach two recorded frames; "
            "roll out longer (steps=null)"
        )
    idx = np.searchsorted(truth.times, pred.times[keep] - 1e-6 * truth.frame_dt)
    idx = np.clip(idx, 0, truth.num_frames - 1)
    if np.any(np.abs(truth.times[idx] - pred.times[keep]) > 1e-3 * truth.frame_dt):
        raise InputError(
            "from_scene: the rollout's frames do not fall on the ground truth's frames (the "
            "settle time is not a whole number of learned steps)"
        )
    metadata = dict(pred.metadata) | {"initial_frames": 1, "steps": int(keep.sum()) - 1}
    return dataclasses.replace(
        pred,
        positions=pred.positions[keep],
        velocities=pred.velocities[keep],
        times=truth.times[idx],
        metadata=metadata,
    )


def whole_job_scalars(scalars: dict, whole: Trajectory) -> None:
    """Set ``scalars`` of a rollout from the scene alone (``whole``, fill and settle
    included): its scalars that pair particles by index are NaN
    (the packing is not LIGGGHTS's), the leaks count the fill and settle too, and the
    simulated time is the whole job's."""
    for key in BY_INDEX_SCALARS:
        scalars[key] = float("nan")
    # A packed particle above the walls (the region rose to hold the bed) is not a leak: each
    # particle is followed from the first frame it lies inside the walls and the box.
    entered = np.full(whole.num_particles, whole.num_frames)
    for f in range(whole.num_frames):
        present = np.isfinite(whole.positions[f]).all(1)
        inside = present & ~inference.outside_scene(whole, f)
        entered = np.where((entered == whole.num_frames) & inside, f, entered)
        if (entered < whole.num_frames).all():
            break
    after = np.arange(whole.num_frames)[:, None, None] >= entered[None, :, None]
    followed = np.where(after, whole.positions, np.nan)
    # Crossings and box exits after that (its first frame is inside by construction).
    leaked = metrics.leaked_mask(followed, whole.scene, whole.times, initial=False).any(0)
    scalars["leaked_particles"] = float(leaked.sum())
    scalars["never_inside_walls"] = float((entered == whole.num_frames).sum())
    first = int(whole.metadata.get("initial_frames", 1)) - 1
    scalars["rollout_simulated_s"] = float(whole.times[-1] - whole.times[first])
    scalars["from_scene"] = 1.0
