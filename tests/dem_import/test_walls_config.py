"""``walls.yaml``: the documented example parses into what it says."""

from __future__ import annotations

from pathlib import Path

from granular_pyg.dem_import.walls_config import read_walls_config
from granular_pyg.scenes import WallMotion

DOCS = Path(__file__).resolve().parents[2] / "docs" / "data.md"


def _docs_example() -> str:
    text = DOCS.read_text()
    section = text[text.index("## Your own LIGGGHTS runs") :]
    start = section.index("```yaml\n") + len("```yaml\n")
    return section[start : section.index("```", start)]


def test_the_documented_walls_yaml_parses(tmp_path):
    path = tmp_path / "walls.yaml"
    path.write_text(_docs_example())
    config = read_walls_config(path)
    assert (config.kind, config.name, config.outflow_z, config.units) == (
        "hopper",
        "my_hopper",
        -0.03,
        "m",
    )
    assert config.materials == {"youngs_modulus": 5e6, "restitution": 0.6, "density": 2500.0}
    assert [(w.file.name, w.units, w.removal_time) for w in config.walls] == [
        ("hopper.stl", None, None),
        ("lid.stl", None, 0.05),
        ("drum.stl", "mm", None),
    ]
    assert config.walls[2].motion == WallMotion("rotation", axis=(0, 1, 0), omega=2.0)
