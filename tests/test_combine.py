"""One dataset over several geometry families, with a family held out."""

from __future__ import annotations

import json
import shutil

import pytest

from granular_pyg.data import load_split
from granular_pyg.data.combine import combine, main
from granular_pyg.errors import InputError
from granular_pyg.samples import SAMPLES_DIR


@pytest.fixture
def families(tmp_path):
    """The bundled hopper and drum samples as two families of one root."""
    root = tmp_path / "general"
    for family in ("hopper", "drum"):
        shutil.copytree(SAMPLES_DIR / family, root / family)
        manifest = json.loads((root / family / "manifest.json").read_text())
        (root / family / "manifest.json").write_text(json.dumps(manifest | {"family": family}))
    return root


def test_families_keep_their_splits_and_a_held_out_one_goes_to_heldout(families):
    path = combine(families, hold_out=["drum"])
    manifest = json.loads(path.read_text())
    assert (
        manifest["families"]["drum"]["held_out"] and not manifest["families"]["hopper"]["held_out"]
    )
    splits = manifest["splits"]
    assert len(splits["heldout"]) == 4 and all(f.startswith("drum/") for f in splits["heldout"])
    assert [len(splits[s]) for s in ("train", "valid", "test")] == [2, 1, 1]
    assert all(f.startswith("hopper/") for s in ("train", "valid", "test") for f in splits[s])
    assert {e["family"] for e in manifest["trajectories"]} == {"hopper", "drum"}
    assert all(p.is_file() for p in load_split(str(families), None, "heldout"))


def test_without_hold_out_every_family_trains(families):
    combine(families)
    train = load_split(str(families), None, "train")
    assert {p.parent.name for p in train} == {"hopper", "drum"} and len(train) == 4


def test_bad_requests_are_named(families, tmp_path, capsys):
    with pytest.raises(InputError, match=r"no family \['silo'\]"):
        combine(families, hold_out=["silo"])
    with pytest.raises(InputError, match="no training trajectory"):
        combine(families, hold_out=["hopper", "drum"])
    (families / "drum" / "traj_0003.h5").unlink()
    with pytest.raises(InputError, match=r"traj_0003\.h5: listed in"):
        combine(families)
    with pytest.raises(SystemExit):
        main([str(tmp_path / "empty")])
    assert capsys.readouterr().err.startswith("error: ")


def test_a_broken_manifest_is_one_clear_error(tmp_path):
    from granular_pyg.data import load_split
    from granular_pyg.errors import InputError

    (tmp_path / "manifest.json").write_text('{"splits": {"train": [')
    with pytest.raises(InputError, match="not a readable JSON manifest"):
        load_split(tmp_path, None, "train")
    (tmp_path / "manifest.json").write_text('{"trajectories": []}')
    with pytest.raises(InputError, match='no "splits" section'):
        load_split(tmp_path, None, "train")
    with pytest.raises(InputError, match=r"data\.root"):
        load_split(None, None, "train")
