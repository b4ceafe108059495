"""Non-overlapping insertion in a Scene's region (as LIGGGHTS's insert/pack): no two particles
overlap and every particle lies entirely inside the region, checked against brute force."""

from __future__ import annotations

import math

import numpy as np
import pytest

from granular_pyg.errors import InputError
from granular_pyg.scenes import ParticleSpec, make_hopper
from granular_pyg.scenes.packing import pack_particles, region_base_area


def _overlaps(pos: np.ndarray, radii: np.ndarray) -> int:
    """Brute force: pairs closer than the sum of their radii."""
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    touch = d < radii[:, None] + radii[None] - 1e-12
    np.fill_diagonal(touch, False)
    return int(touch.sum() // 2)


SPECS = {
    "box": ParticleSpec(300, 0.002, (-0.02, -0.01, 0.0), (0.02, 0.01, 0.04)),
    "cylinder": ParticleSpec.cylinder_region(300, 0.002, (0.01, -0.005), 0.02, (0.01, 0.05)),
    "sizes": ParticleSpec(
        400,
        0.002,
        (0.0, 0.0, 0.0),
        (0.04, 0.03, 0.05),
        radii=(0.001, 0.0015, 0.002),
        radius_weights=(0.5, 0.3, 0.2),
    ),
}


@pytest.mark.parametrize("name", sorted(SPECS))
@pytest.mark.parametrize("seed", [0, 7])
def test_no_two_particles_overlap_and_all_lie_inside_the_region(name, seed):
    spec = SPECS[name]
    packing = pack_particles(spec, seed=seed)
    pos, r = packing.positions, packing.radii
    assert pos.shape == (spec.count, 3) and r.shape == (spec.count,)
    assert _overlaps(pos, r) == 0
    lo, hi = packing.region_lo, packing.region_hi
    assert lo.tolist() == list(spec.fill_lo)  # only the top may rise
    assert (pos[:, 2] - r >= lo[2] - 1e-12).all() and (pos[:, 2] + r <= hi[2] + 1e-12).all()
    if spec.fill_shape == "box":
        assert (pos - r[:, None] >= lo - 1e-12).all() and (pos + r[:, None] <= hi + 1e-12).all()
    else:
        cx, cy, radius, _, _ = spec.cylinder
        assert (np.hypot(pos[:, 0] - cx, pos[:, 1] - cy) + r <= radius + 1e-12).all()
    assert set(np.unique(r)) <= set(spec.size_distribution[0])
    again = pack_particles(spec, seed=seed)
    assert np.array_equal(again.positions, pos)


def test_the_size_distribution_follows_its_number_fractions():
    spec = SPECS["sizes"]
    r = pack_particles(spec, seed=3).radii
    counts = [np.mean(r == size) for size in spec.size_distribution[0]]
    assert counts == pytest.approx([0.5, 0.3, 0.2], abs=0.07)


def test_a_region_too_small_for_its_particles_is_made_taller_or_refused():
    spec = ParticleSpec(200, 0.002, (0.0, 0.0, 0.0), (0.02, 0.02, 0.02))
    solid = 200 * 4 / 3 * math.pi * 0.002**3
    packing = pack_particles(spec, seed=0, max_fraction=0.2)
    # Raised to hold them at 0.2 at least (and by half its height per 100 jammed rounds).
    assert packing.region_hi[2] >= solid / 0.2 / 0.02**2 - 1e-12
    assert packing.fraction <= 0.2 + 1e-12
    assert _overlaps(packing.positions, packing.radii) == 0
    with pytest.raises(InputError, match=r"only \d+ of 200 particles fit .* region taller"):
        pack_particles(spec, seed=0, ceiling=0.02, max_rounds=30)


def test_the_hoppers_own_region_holds_its_bed():
    scene = make_hopper(num_particles=600)
    packing = pack_particles(scene.particles, seed=2)
    assert _overlaps(packing.positions, packing.radii) == 0
    lo = np.asarray(scene.particles.fill_lo)
    assert (packing.positions[:, :2] >= lo[:2]).all()


def test_the_regions_base_area_is_the_box_or_the_cylinders_disc():
    assert region_base_area(SPECS["box"]) == pytest.approx(0.04 * 0.02)
    assert region_base_area(SPECS["cylinder"]) == pytest.approx(math.pi * 0.02**2)
