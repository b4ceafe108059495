"""Everything about a checkpoint file, in one place: reading it safely, the model it describes
and its weights, the model card, the config it stores (and its migration from older keys),
resuming from it, fine-tuning from it, and the names of the shipped ones.

Trust: a checkpoint is a file users receive, not a config they write. It is read with torch's
weights-only unpickler (:mod:`~granular_pyg.checkpoint.files`), and its saved config builds only
the package's own model classes (:mod:`~granular_pyg.checkpoint.model`); see
``docs/robustness.md``.

Rooms: :mod:`.files` (read, pretrained names), :mod:`.model` (build, load weights),
:mod:`.card` (model card), :mod:`.saved_config` (older keys), :mod:`.resume` (what a checkpoint
stores, resume check), :mod:`.fine_tune` (fine-tuning initialisation).
"""

from granular_pyg.checkpoint.card import card_of_trajectories, model_card, outside_training
from granular_pyg.checkpoint.files import (
    PREFIX,
    PRETRAINED,
    PRETRAINED_DIR,
    read_checkpoint,
    read_training_checkpoint,
    resolve_checkpoint,
    safe_load,
)
from granular_pyg.checkpoint.model import (
    MODEL_TARGETS,
    build_model,
    check_model_config,
    load_simulator,
    load_weights,
    to_plain,
    whole_multiple,
)
from granular_pyg.checkpoint.resume import DERIVED_KEYS, RESUME_KEYS, check_resume, saved_config
from granular_pyg.checkpoint.saved_config import migrate_config

__all__ = [
    "DERIVED_KEYS",
    "MODEL_TARGETS",
    "PREFIX",
    "PRETRAINED",
    "PRETRAINED_DIR",
    "RESUME_KEYS",
    "build_model",
    "card_of_trajectories",
    "check_model_config",
    "check_resume",
    "load_simulator",
    "load_weights",
    "migrate_config",
    "model_card",
    "outside_training",
    "read_checkpoint",
    "read_training_checkpoint",
    "resolve_checkpoint",
    "safe_load",
    "saved_config",
    "to_plain",
    "whole_multiple",
]
