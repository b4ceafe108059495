"""The reflection toy experiment (paper Appendix B.1): reflection formula, R1-R4 features, a
short end-to-end run and config errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from granular_pyg.config import compose
from granular_pyg.errors import InputError
from granular_pyg.experiments.reflection import (
    KINDS,
    WALLS,
    make_reflection_data,
    reflect,
    represent,
    run_experiment,
)

REPO = Path(__file__).resolve().parents[2]
PNG = b"\x89PNG\r\n\x1a\n"
TINY = [
    "seeds=[0,1]",
    "train_samples=64",
    "test_samples=32",
    "steps=20",
    "batch_size=16",
    "hidden=8",
    "layers=1",
    "figure_rays=2",
    "progress=false",
]

finite = st.floats(-10, 10, allow_nan=False, allow_subnormal=False)
vec = st.tuples(finite, finite, finite)
nonzero = vec.filter(lambda n: sum(x * x for x in n) > 1e-2)


def _bits(x: torch.Tensor) -> torch.Tensor:
    """Bit pattern, so -0.0 and +0.0 differ."""
    return x.view(torch.int64)


def test_reflection_at_axis_aligned_walls_is_exact():
    v = torch.tensor([[1.0, 2.0, 3.0]] * 4)
    n = torch.tensor([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, 2.0]])
    expected = torch.tensor([[-1.0, 2.0, 3.0]] * 2 + [[1.0, 2.0, -3.0]] * 2)
    assert torch.equal(reflect(v, n), expected)
    # Oblique wall: v = (1, 0, 0) at n = (1, 1, 0) goes to (0, -1, 0).
    assert torch.equal(
        reflect(torch.tensor([1.0, 0.0, 0.0]), torch.tensor([1.0, 1.0, 0.0])),
        torch.tensor([0.0, -1.0, 0.0]),
    )


@settings(max_examples=200, deadline=None)
@given(v=vec, n=nonzero)
def test_reflecting_twice_returns_v_and_keeps_its_length(v, n):
    v, n = torch.tensor(v, dtype=torch.float64), torch.tensor(n, dtype=torch.float64)
    once = reflect(v, n)
    torch.testing.assert_close(reflect(once, n), v, atol=1e-9, rtol=1e-9)
    torch.testing.assert_close(once.norm(), v.norm(), atol=1e-9, rtol=1e-9)
    torch.testing.assert_close(reflect(v, -n), once, atol=0, rtol=0)  # sign of n is irrelevant


def test_zero_normal_is_an_input_error():
    with pytest.raises(InputError, match="n: a zero normal"):
        reflect(torch.ones(3), torch.zeros(3))


def test_training_rays_travel_into_their_walls():
    data = make_reflection_data(400, torch.Generator().manual_seed(0))
    assert torch.bincount(data["wall"]).tolist() == [100] * len(WALLS)
    assert ((data["incident"] * data["normals"]).sum(1) > 0).all()  # v . n > 0
    assert ((data["reflected"] * data["normals"]).sum(1) < 0).all()
    torch.testing.assert_close(data["incident"].norm(dim=1), torch.ones(400))


@settings(max_examples=100, deadline=None)
@given(normals=st.lists(nonzero, min_size=1, max_size=8))
def test_canonical_features_ignore_the_orientation_raw_ones_do_not(normals):
    n = torch.tensor(normals, dtype=torch.float64)
    for kind in ("R3", "R4"):
        assert torch.equal(_bits(represent(n, kind)), _bits(represent(-n, kind)))
    for kind in ("R1", "R2"):
        assert not torch.equal(represent(n, kind), represent(-n, kind))
    assert [represent(n, k).shape[1] for k in KINDS] == [3, 6, 3, 6]


def test_representations_of_the_training_walls():
    n = torch.tensor(list(WALLS.values()))  # left, right, bottom, top (outward)
    assert torch.equal(represent(n, "R2"), torch.cat([n, -n], 1))
    # f_o picks (-1, 0, 0) for both x walls and (0, 0, -1) for both z walls.
    expected = torch.tensor([[-1.0, 0.0, 0.0]] * 2 + [[0.0, 0.0, -1.0]] * 2)
    assert torch.equal(represent(n, "R3"), expected)
    assert torch.equal(represent(n, "R4"), torch.cat([expected, -expected], 1))
    with pytest.raises(InputError, match="kind"):
        represent(n, "R5")


def test_short_run_writes_table_json_and_both_figures(tmp_path):
    results = run_experiment(compose("reflection", [*TINY, f"out={tmp_path}"]))
    assert list(results["representations"]) == ["R1", "R2", "R3", "R4"]
    for kind, row in results["representations"].items():
        assert len(row["same"]["per_seed"]) == 2
        if kind in ("R3", "R4"):  # identical features, so identical errors
            assert row["same"]["per_seed"] == row["inverted"]["per_seed"]
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["seeds"] == [0, 1]
    assert saved["representations"]["R1"]["inverted"]["mean"] >= 0
    assert "| R4 |" in (tmp_path / "table.md").read_text()
    csv_lines = (tmp_path / "table.csv").read_text().splitlines()
    assert csv_lines[0].startswith("representation,features,same_mean,same_std")
    assert len(csv_lines) == 5
    for name in ("reflection_same.png", "reflection_inverted.png"):
        assert (tmp_path / "figures" / name).read_bytes()[:8] == PNG


def test_hydra_entry_point_runs(tmp_path):
    out = tmp_path / "run"
    cmd = [
        sys.executable,
        "-m",
        "granular_pyg.experiments.reflection",
        *TINY,
        "seeds=[3]",
        "representations=[R1,R3]",
        f"hydra.run.dir={out}",
    ]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "| R3 |" in proc.stdout and str(out) in proc.stdout
    saved = json.loads((out / "results.json").read_text())
    assert list(saved["representations"]) == ["R1", "R3"]
    assert saved["command"].startswith("python -m granular_pyg.experiments.reflection")
    assert (out / "figures" / "reflection_inverted.png").read_bytes()[:8] == PNG


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("steps=0", "steps"),
        ("lr=-1", "lr"),
        ("seeds=[]", "seeds"),
        ("representations=[R1,R9]", "representations"),
        ("train_samples=3", "train_samples"),
        ("batch_size=1.5", "batch_size"),
        ("progress=maybe", "progress"),
    ],
)
def test_bad_config_values_are_input_errors(tmp_path, override, key):
    with pytest.raises(InputError, match=f"^{key}: "):
        run_experiment(compose("reflection", [*TINY, f"out={tmp_path}", override]))


def test_unresolvable_out_outside_hydra_is_an_input_error():
    with pytest.raises(InputError, match=r"^out: "):
        run_experiment(compose("reflection", TINY))
