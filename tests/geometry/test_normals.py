"""triangle_normals, the paper's partial order f_o and canonical_normals."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from granular_pyg.errors import InputError
from granular_pyg.geometry import canonical_normals, orientation_key, triangle_normals


def _bits(x: torch.Tensor) -> torch.Tensor:
    """Bit pattern, so -0.0 and +0.0 differ."""
    return x.view(torch.int64 if x.dtype == torch.float64 else torch.int32)


def paper_f_o(n) -> int:
    """The paper's formula, literally: sum_{i=1}^{3} 3^(i-1) (sgn(n_i) + 1)."""
    return sum(3 ** (i - 1) * (int(np.sign(n[i - 1])) + 1) for i in range(1, 4))


@pytest.mark.parametrize("signs", list(itertools.product((-1, 0, 1), repeat=3)))
def test_orientation_key_matches_the_paper_on_all_27_sign_patterns(signs):
    n = torch.tensor(signs, dtype=torch.float64) * torch.tensor([0.3, 2.0, 0.7])
    assert orientation_key(n).item() == paper_f_o(n.tolist())
    assert orientation_key(n, zero_tol=0.0).item() == paper_f_o(n.tolist())
    assert orientation_key(-n).item() == 26 - paper_f_o(n.tolist())


def test_round_off_components_count_as_zero():
    # The same wall, stored with round-off of either sign in z, gets the same feature.
    a = torch.tensor([[1.0, 0.0, 1e-12]], dtype=torch.float64)
    b = torch.tensor([[1.0, 0.0, -1e-12]], dtype=torch.float64)
    assert orientation_key(a).item() == orientation_key(b).item() == paper_f_o([1, 0, 0])
    torch.testing.assert_close(canonical_normals(a), canonical_normals(b))


def test_canonical_order_puts_the_smaller_key_first():
    n = torch.tensor([[0.0, 0.0, 1.0], [1.0, -1.0, 0.0], [0.0, 0.0, 0.0]])
    out = canonical_normals(n)
    assert out.shape == (3, 6)
    # f_o(0,0,1) = 1 + 3 + 18 = 22 > f_o(0,0,-1) = 4, so -n comes first.
    assert out[0].tolist() == [0.0, 0.0, -1.0, 0.0, 0.0, 1.0]
    # f_o(1,-1,0) = 2 + 0 + 9 = 11 < f_o(-1,1,0) = 15: n stays first.
    assert out[1].tolist() == [1.0, -1.0, 0.0, -1.0, 1.0, 0.0]
    assert out[2].tolist() == [0.0] * 6
    assert (orientation_key(out[:, :3]) <= orientation_key(out[:, 3:])).all()


normals = arrays(
    np.float64,
    (32, 3),
    elements=st.one_of(
        st.floats(-1, 1, allow_subnormal=False), st.sampled_from([0.0, -0.0, 1e-13, -1e-13])
    ),
)


@settings(max_examples=100, deadline=None)
@given(normals, st.sampled_from([torch.float32, torch.float64]))
def test_flipping_every_normal_leaves_the_output_bit_identical(data, dtype):
    n = torch.from_numpy(data).to(dtype)
    out, flipped = canonical_normals(n), canonical_normals(-n)
    assert torch.equal(_bits(out), _bits(flipped))
    assert not torch.signbit(out[out == 0]).any()  # no -0.0 survives
    # Both orientations are present, and the keys are ordered.
    torch.testing.assert_close(out[:, 3:], -out[:, :3] + 0.0)
    assert (orientation_key(out[:, :3]) <= orientation_key(out[:, 3:])).all()


def test_triangle_normals_follow_the_right_hand_rule_and_flip_with_winding():
    tri = torch.tensor([[(0, 0, 0), (2, 0, 0), (0, 3, 0)], [(0, 0, 0), (0, 0, 1), (0, 1, 0)]])
    n = triangle_normals(tri.double())
    torch.testing.assert_close(n, torch.tensor([[0.0, 0, 1], [-1.0, 0, 0]], dtype=torch.float64))
    torch.testing.assert_close(triangle_normals(tri.double()[:, [0, 2, 1]]), -n)
    # ...and canonical normals cannot tell the two windings apart.
    assert torch.equal(canonical_normals(n), canonical_normals(-n))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_degenerate_triangle_has_a_zero_normal_not_nan(dtype):
    tri = torch.tensor(
        [[(0, 0, 0), (0, 0, 0), (0, 0, 0)], [(0, 0, 0), (1, 1, 1), (2, 2, 2)]], dtype=dtype
    )
    n = triangle_normals(tri)
    assert torch.equal(n, torch.zeros_like(n))


def test_tiny_triangles_still_get_unit_normals():
    tri = torch.tensor([[(0, 0, 0), (1e-15, 0, 0), (0, 1e-15, 0)]], dtype=torch.float64)
    torch.testing.assert_close(triangle_normals(tri), torch.tensor([[0.0, 0, 1]]).double())


def test_wrong_shape_is_a_clear_error():
    with pytest.raises(InputError, match=r"normals: expected shape \[\*, 3\]"):
        canonical_normals(torch.zeros(4, 2))
