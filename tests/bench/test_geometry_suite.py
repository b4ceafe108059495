"""`python -m granular_pyg.bench suite=geometry` runs end to end and writes its four files."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from granular_pyg.bench.meshes import funnel_mesh, packed_particles
from granular_pyg.bench.report import Target
from granular_pyg.geometry import triangle_normals

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("num_triangles", [18, 424, 2000, 20000])
def test_funnel_mesh_has_exactly_the_requested_triangles(num_triangles):
    vertices, faces = funnel_mesh(num_triangles)
    assert faces.shape == (num_triangles, 3)
    assert int(faces.max()) < len(vertices)
    normals = triangle_normals(vertices[faces])
    assert (normals.norm(dim=1) > 0.99).all()  # no degenerate triangle


def test_packed_particles_stay_inside_the_funnel_and_apart():
    points = packed_particles(2000, radius=0.001)
    assert points.shape == (2000, 3)
    assert points[:, 2].min() >= 0.001 * 0.95
    gaps = torch.cdist(points[:500], points[:500]) + torch.eye(500)
    assert gaps.min() > 2 * 0.001 * 0.9  # lattice spacing minus jitter


def test_target_comparison():
    assert Target("a", 25.0, ">=", 20).met
    assert not Target("b", 2.5, "<=", 2).met


def test_geometry_suite_writes_results_json_csv_markdown_and_png(tmp_path):
    out = tmp_path / "bench"
    cmd = [
        sys.executable,
        "-m",
        "granular_pyg.bench",
        "suite=geometry",
        "suite.run.num_particles=2000",
        "suite.run.triangle_counts=[424,2000]",
        "repeats=1",
        f"hydra.run.dir={out}",
    ]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "target speedup vs dense at 2000x424" in proc.stdout
    results = json.loads((out / "results.json").read_text())
    assert results["geometry/2000x424/near_pairs"] > 0
    assert results["geometry/2000x424/speedup_vs_dense"] > 1.0
    assert "query_ratio_2000_vs_424_same_pairs" in " ".join(results)
    assert {"machine", "versions", "commit", "command"} <= set(results)
    assert results["command"].startswith("python -m granular_pyg.bench suite=geometry")
    csv_lines = (out / "results.csv").read_text().splitlines()
    assert csv_lines[0].startswith("triangles,particles,near_pairs")
    assert len(csv_lines) == 4  # header, two meshes, the matched-pairs row
    assert "## Targets" in (out / "report.md").read_text()
    assert (out / "results.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
