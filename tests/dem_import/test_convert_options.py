"""ConvertOptions: the converter's options in one object, however they are passed."""

from __future__ import annotations

import pytest

from granular_pyg.dem_import.convert import (
    POSITIONAL,
    ConvertOptions,
    trajectories_from_dumps,
    trajectory_from_dumps,
)
from tests.dem.dump_text import falling, write_dump


def test_positional_keyword_and_object_forms_are_one_set_of_options():
    by_keyword = ConvertOptions.of(None, (), {"stl_files": ["a.stl"], "dem_dt": 2e-5})
    by_position = ConvertOptions.of(None, (["a.stl"], 2e-5), {})
    by_object = ConvertOptions.of(ConvertOptions(stl_files=["a.stl"]), (), {"dem_dt": 2e-5})
    assert (
        by_keyword == by_position == by_object == ConvertOptions(stl_files=["a.stl"], dem_dt=2e-5)
    )
    assert tuple(f for f in ConvertOptions.__dataclass_fields__)[: len(POSITIONAL)] == POSITIONAL


def test_an_option_given_twice_or_unknown_is_refused():
    with pytest.raises(TypeError, match="given twice"):
        ConvertOptions.of(None, (["a.stl"],), {"stl_files": ["b.stl"]})
    with pytest.raises(TypeError):
        ConvertOptions.of(None, (), {"no_such_option": 1})


def test_both_converters_take_the_same_options(tmp_path):
    dump = write_dump(tmp_path / "d.dump", falling(range(0, 800, 100)))
    options = ConvertOptions(dem_dt=2e-5)
    one = trajectory_from_dumps(dump, options=options)
    parts = trajectories_from_dumps(dump, options=options).parts
    assert len(parts) == 1
    assert parts[0].num_frames == one.num_frames
    assert trajectory_from_dumps(dump, dem_dt=2e-5).num_frames == one.num_frames
