"""Opening a stranger's checkpoint runs none of its code (issue 36, family 1).

A checkpoint is read with torch's weights-only unpickler and its saved config builds only the
package's own model classes. Each reader is given a hostile file (a pickle payload, or a config
``_target_`` that is no model class) and must refuse it with one clear ``InputError`` and make
no marker file; the shipped checkpoints and a fresh training checkpoint load with
``weights_only=True``. The commands themselves are run on hostile files in
``tests/test_bad_input_commands.py``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from granular_pyg.checkpoint import (
    PRETRAINED,
    load_simulator,
    read_checkpoint,
    resolve_checkpoint,
    safe_load,
)
from granular_pyg.errors import InputError
from tests import hostile

PACKAGE = Path(__file__).resolve().parent.parent / "granular_pyg"
REFUSED = r"asks to run (builtins\.)?exec while it is read, so it was refused unread"
TARGETS = [("open", False), ("write_text", False), ("torch.load", False), ("open", True),
           ("torch.load", True)]  # fmt: skip


def test_the_payload_is_live(tmp_path):
    """The hostile file really runs code when read the old way (so the tests below mean
    something)."""
    marker = tmp_path / "pwned"
    path = hostile.pickle_payload(tmp_path / "evil.ckpt", marker)
    torch.load(path, weights_only=False)
    assert marker.read_text() == "ran"


@pytest.mark.parametrize("name", sorted(PRETRAINED))
def test_every_shipped_checkpoint_loads_with_weights_only(name):
    path = resolve_checkpoint(f"pretrained:{name}")
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    assert "state_dict" in ckpt and "model" in ckpt["config"]
    _, config = load_simulator(f"pretrained:{name}")
    assert config["model_card"]


def test_a_pickle_payload_is_refused_unrun_by_every_reader(tmp_path):
    from granular_pyg.checkpoint.fine_tune import with_initial_model
    from granular_pyg.checkpoint.resume import check_resume
    from granular_pyg.pretrained.export import export

    marker = tmp_path / "pwned"
    path = hostile.pickle_payload(tmp_path / "evil.ckpt", marker)
    before = path.read_bytes()
    cfg = OmegaConf.create(
        {"init": str(path), "data": {"root": None, "sample": "hopper"}, "model": {}}
    )
    readers = {
        "read": lambda: read_checkpoint(path),
        "load_simulator (rollout, evaluate, stress, bench, one_step_bias)": lambda: load_simulator(
            path
        ),
        "fine-tuning init=": lambda: with_initial_model(cfg),
        "resume ckpt_path=": lambda: check_resume(str(path), cfg),
        "pretrained.export": lambda: export(path, "hopper", "hopper", out=tmp_path / "o.ckpt"),
    }
    for what, read in readers.items():
        with pytest.raises(InputError, match=REFUSED):
            read()
        assert not marker.exists(), f"{what} ran the payload"
    assert path.read_bytes() == before and not (tmp_path / "o.ckpt").exists()


@pytest.mark.parametrize(("how", "nested"), TARGETS)
def test_a_config_target_that_is_no_model_class_is_refused_unrun(tmp_path, how, nested):
    from granular_pyg.checkpoint.fine_tune import with_initial_model
    from granular_pyg.pretrained.export import export

    marker = tmp_path / "pwned"
    path = hostile.config_target(tmp_path / "evil.ckpt", marker, how, nested)
    where = "model.processor._target_" if nested else "model._target_"
    cfg = OmegaConf.create(
        {"init": str(path), "data": {"root": None, "sample": "hopper"}, "model": {}}
    )
    for read in (
        lambda: load_simulator(path),
        lambda: with_initial_model(cfg),
        lambda: export(path, "hopper", "hopper", out=tmp_path / "o.ckpt"),
    ):
        with pytest.raises(InputError, match=rf"{where}=.*not one of the package's model classes"):
            read()
        assert not marker.exists()


def test_a_fresh_training_checkpoint_loads_with_weights_only(tmp_path):
    """What Lightning pickles (loops, callbacks, optimiser, RNG states) and what the project
    adds (config, model card) are tensors and plain data."""
    from granular_pyg.train import train
    from tests.training.test_train import _steps_cfg

    train(_steps_cfg(1, "trainer.fast_dev_run=false", "checkpoint.every_n_train_steps=1"), tmp_path)
    last = tmp_path / "checkpoints" / "last.ckpt"
    ckpt = torch.load(last, map_location="cpu", weights_only=True)
    assert isinstance(ckpt["config"], dict) and type(ckpt["config"]["model"]) is dict
    sim, _ = load_simulator(last)
    assert float(sim.dt) > 0


def test_no_module_but_the_checkpoint_reader_calls_torch_load():
    """Every file the package reads with ``torch.load`` goes through
    :func:`granular_pyg.checkpoint.safe_load` (weights only)."""
    calls = []
    for path in PACKAGE.rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            func = node.func if isinstance(node, ast.Call) else None
            if (
                isinstance(func, ast.Attribute)
                and func.attr == "load"
                and getattr(func.value, "id", "") == "torch"
            ):
                calls.append(str(path.relative_to(PACKAGE)))
    assert calls == ["checkpoint/files.py"], calls


def test_the_readers_of_every_command_use_the_safe_loader():
    """rollout, evaluate, stress, bench (rollout_speed, liggghts, pareto) and
    experiments.one_step_bias load their model with ``load_simulator``, which is the checkpoint
    module's (safe) one."""
    import granular_pyg.bench.rollout_speed as rollout_speed
    import granular_pyg.evaluate as evaluate
    import granular_pyg.experiments.one_step_bias as one_step_bias
    import granular_pyg.rollout as rollout
    import granular_pyg.stress as stress
    from granular_pyg.checkpoint.model import load_simulator as safe

    for module in (rollout, evaluate, stress, rollout_speed, one_step_bias):
        assert module.load_simulator is safe, module.__name__


def test_a_bare_tensor_a_state_dict_and_mismatched_weights_are_one_line_errors(tmp_path):
    ckpt = hostile.shipped()
    torch.save(torch.zeros(3), tmp_path / "tensor.ckpt")
    torch.save(ckpt["state_dict"], tmp_path / "weights.ckpt")
    wrong = hostile.shipped()
    wrong["config"]["model"]["history"] = 3  # the weights were trained with 5
    torch.save(wrong, tmp_path / "wrong.ckpt")
    for name, words in (
        ("tensor.ckpt", "holds a Tensor, not a granular_pyg training checkpoint"),
        ("weights.ckpt", "is a bare state_dict"),
        ("wrong.ckpt", r"its weights do not fit the model its config describes \(.* of another "
         "shape, first"),
    ):  # fmt: skip
        with pytest.raises(InputError, match=words) as info:
            load_simulator(tmp_path / name)
        assert "\n" not in str(info.value)


def test_safe_load_names_a_folder_and_a_missing_file(tmp_path):
    with pytest.raises(InputError, match="is a folder; pass a checkpoint file"):
        safe_load(tmp_path)
    with pytest.raises(InputError, match=r"no checkpoint at .*pretrained:drum"):
        safe_load(tmp_path / "nope.ckpt")


def test_a_malformed_model_card_is_one_warning_not_a_traceback(capsys):
    from granular_pyg.inference import warn_outside_training
    from granular_pyg.io import read_trajectory
    from granular_pyg.samples import sample_files

    truth = read_trajectory(sample_files("hopper", "test")[0])
    card = {"training_data": {"scene_kinds": ["hopper"], "particle_radius_m": "x", "materials": 3}}
    found = warn_outside_training({"model_card": card}, truth, "X.h5")
    assert found == ["the checkpoint's model card is malformed, so its training ranges are not "
                     "checked"]  # fmt: skip
    assert capsys.readouterr().err.count("warning:") == 1


def test_a_config_asking_for_a_huge_model_is_refused_before_anything_is_allocated(tmp_path):
    """The model is first built on the meta device and compared with the weights: a hostile
    config asking for 3e11 parameters is refused without allocating them."""
    huge = hostile.shipped()
    huge["config"]["model"]["latent"] = huge["config"]["model"]["processor"]["latent"] = 100_000
    torch.save(huge, tmp_path / "huge.ckpt")
    with pytest.raises(InputError, match=r"its weights do not fit the model its config describes"):
        load_simulator(tmp_path / "huge.ckpt")


def test_fine_tuning_a_shipped_model_writes_a_checkpoint_that_loads_weights_only(tmp_path):
    """``init=pretrained:hopper`` builds the model from the checkpoint's config (its own classes
    only, checked against its weights first) and the run's checkpoint is plain data."""
    from granular_pyg.train import train
    from tests.training.test_train import _steps_cfg

    cfg = _steps_cfg(1, "init=pretrained:hopper", "trainer.fast_dev_run=false")
    train(cfg, tmp_path)
    ckpt = torch.load(tmp_path / "checkpoints" / "last.ckpt", weights_only=True)
    assert ckpt["model_card"]["fine_tuned_from"] == "pretrained:hopper"
    assert ckpt["config"]["model"]["latent"] == hostile.shipped()["config"]["model"]["latent"]
    # the shipped hopper sees each scene in its own frame: random frames are switched off
    assert ckpt["config"]["model"]["canonical_frame"] and not ckpt["config"]["data"]["augment"]
