"""`generate` splits by count (`splits={train: 2, valid: 1, test: 3}`) as well as by fraction."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig

from granular_pyg.errors import InputError
from granular_pyg.generate import _n_from_counts, plan_trajectories, split_counts

CONF = Path(__file__).resolve().parents[1] / "conf"


def _cfg(*overrides: str):
    """The generate config as the command line makes it, with its Hydra runtime set."""
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose("generate", overrides=list(overrides), return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    return cfg


def test_counts_are_taken_as_they_are():
    counts = {"train": 2, "valid": 1, "test": 3}
    assert split_counts(6, counts) == counts
    assert split_counts(1, {"train": 1, "valid": 0, "test": 0}) == {
        "train": 1,
        "valid": 0,
        "test": 0,
    }
    # Fractions keep their rounding: valid and test round(n f), at least one each.
    assert split_counts(6, {"train": 0.5, "valid": 0.17, "test": 0.33}) == {
        "valid": 1,
        "test": 2,
        "train": 3,
    }


def test_counts_that_do_not_add_up_to_n_are_refused_naming_both():
    with pytest.raises(InputError, match=r"add up to 6 trajectories, but n=4; leave n= out"):
        split_counts(4, {"train": 2, "valid": 1, "test": 3})
    with pytest.raises(InputError, match="no training trajectory"):
        split_counts(2, {"train": 0, "valid": 1, "test": 1})
    with pytest.raises(InputError, match="unknown splits"):
        split_counts(3, {"train": 2, "tset": 1})


def test_the_command_line_takes_n_from_the_counts():
    cfg = _n_from_counts(_cfg("splits={train: 2, valid: 1, test: 3}"))
    assert cfg.n == 6
    plan = plan_trajectories(cfg)
    assert [e["split"] for e in plan] == ["train"] * 2 + ["valid"] + ["test"] * 3
    # With n= given, the two must agree.
    cfg = _n_from_counts(_cfg("n=5", "splits={train: 2, valid: 1, test: 3}"))
    with pytest.raises(InputError, match="but n=5"):
        plan_trajectories(cfg)
    # Fractions leave n alone.
    assert _n_from_counts(_cfg("splits={train: 0.5, valid: 0.25, test: 0.25}")).n == 4
