"""Reading a checkpoint file safely, and the names of the shipped (pretrained) ones.

A checkpoint is a pickle, and a pickle can name any Python callable to run while it is read.
Checkpoints are files users receive (the shipped models invite passing them around), so they
are **never** read with ``torch.load(weights_only=False)``: :func:`read_checkpoint` uses torch's
weights-only unpickler, which rebuilds tensors and plain data (dicts, lists, strings, numbers)
and refuses every other global (:data:`SAFE_GLOBALS` would allow-list more; none is needed). A
file that names anything else is refused with one line saying what it names, before any of it
runs.
"""

from __future__ import annotations

import pickle
import re
from pathlib import Path

import torch

from granular_pyg.errors import InputError

__all__ = [
    "PREFIX",
    "PRETRAINED",
    "PRETRAINED_DIR",
    "SAFE_GLOBALS",
    "read_checkpoint",
    "read_training_checkpoint",
    "resolve_checkpoint",
    "safe_load",
]

PREFIX = "pretrained:"

#: name -> file in :data:`PRETRAINED_DIR` (``granular_pyg/pretrained/``).
PRETRAINED = {
    "hopper": "hopper_v3.ckpt",
    "drum": "drum_v3.ckpt",
    "fast_hopper": "fast_hopper_v3.ckpt",  # equivariant, latent 32, k = 16: the speed model
    "fast_drum": "fast_drum_v3.ckpt",  # equivariant, latent 32, k = 8: the drum's speed model
}

#: The folder of the shipped checkpoints (inside the installed package).
PRETRAINED_DIR = Path(__file__).resolve().parent.parent / "pretrained"


#: Globals beyond torch's own defaults (tensors, plain containers and numbers) that the
#: weights-only unpickler may rebuild. None is needed: every checkpoint this project has written
#: (Lightning's, the shipped ones) holds tensors and plain data only (the config and the model
#: card as dicts, the RNG states as tensors and numbers; no ``save_hyperparameters``, so no
#: OmegaConf container). A type added here must run no code of the file's choosing.
SAFE_GLOBALS: list = []


def available_pretrained() -> list[str]:
    """The shipped pretrained names whose file is present."""
    return sorted(n for n, f in PRETRAINED.items() if (PRETRAINED_DIR / f).is_file())


def resolve_checkpoint(ckpt: str | Path, name: str = "ckpt") -> Path:
    """The file of ``ckpt``: ``pretrained:<name>`` names a shipped checkpoint, anything else is
    a path.

    Raises:
        InputError: an unknown or missing pretrained name (listing the available ones).
    """
    text = str(ckpt)
    if not text.strip():
        raise InputError(
            f"{name}: empty; pass a checkpoint file (<run>/checkpoints/last.ckpt) or "
            + " / ".join(f"{PREFIX}{n}" for n in available_pretrained())
        )
    if not text.startswith(PREFIX):
        return Path(ckpt)
    wanted = text[len(PREFIX) :]
    available = available_pretrained()
    if wanted not in available:
        raise InputError(
            f"{name}: no pretrained model {wanted!r}; available: "
            + ", ".join(f"{PREFIX}{n}" for n in available)
        )
    return PRETRAINED_DIR / PRETRAINED[wanted]


#: What torch's weights-only unpickler says when a file asks for more than tensors and plain
#: data (a global, an object to build or a function to call), besides ``GLOBAL <name>``.
_REFUSED_OBJECT = ("Can only create new object", "Can only build", "Trying to call reduce")


def _unsafe_name(exc: BaseException) -> str | None:
    """The global a refused pickle names (torch's message: ``GLOBAL os.system was not an
    allowed global``), ``"a Python object"`` for an object it refused to build, or None when
    the failure is of another kind (a corrupt or truncated file)."""
    text = str(exc)
    found = re.search(r"GLOBAL ([\w.]+)", text)
    if found:
        return found.group(1)
    if any(words in text for words in _REFUSED_OBJECT):
        return "a Python object"
    return None


def safe_load(path: str | Path, name: str = "ckpt", map_location: str = "cpu"):
    """The contents of the torch file ``path``, read with the weights-only unpickler.

    Raises:
        InputError: naming the option ``name``: no such file; a file that names Python code or
            objects other than tensors and plain data (refused, nothing of it run); a truncated
            or corrupt file.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{name}: {path} is a folder; pass a checkpoint file (.ckpt)")
    if not path.is_file():
        raise InputError(
            f"{name}: no checkpoint at {path}; pass a file from <run>/checkpoints/ or one of "
            + ", ".join(f"{PREFIX}{n}" for n in sorted(PRETRAINED))
        )
    try:
        with torch.serialization.safe_globals(SAFE_GLOBALS):
            return torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        what = _unsafe_name(exc)
        if what is not None:
            raise InputError(
                f"{name}: {path} asks to run {what} while it is read, so it was refused unread "
                "(a checkpoint holds only tensors and plain data); use a checkpoint from a "
                "source you trust, or re-export it with python -m granular_pyg.pretrained.export"
            ) from None
        why = next((line for line in reversed(str(exc).splitlines()) if "Unsupported" in line), "")
        raise InputError(
            f"{name}: {path} is not a readable checkpoint ({why or 'not a torch file'}); was it "
            "truncated?"
        ) from None
    except OSError:
        raise
    except Exception as exc:  # torch raises several types for corrupt files
        raise InputError(
            f"{name}: {path} is not a readable checkpoint ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else ''}); was it truncated?"
        ) from None


def read_checkpoint(
    path: str | Path, name: str = "ckpt", map_location: str = "cpu"
) -> tuple[Path, dict]:
    """The file and contents of checkpoint ``path`` (a file or ``pretrained:<name>``), read
    safely (:func:`safe_load`).

    Raises:
        InputError: naming the option ``name``: no such file, an unsafe or unreadable file, or
            one that does not hold a dict (a bare tensor, a list).
    """
    path = resolve_checkpoint(path, name)
    ckpt = safe_load(path, name, map_location)
    if not isinstance(ckpt, dict):
        raise InputError(
            f"{name}: {path} holds a {type(ckpt).__name__}, not a granular_pyg training "
            "checkpoint; pass a file from <run>/checkpoints/ (written by python -m "
            "granular_pyg.train)"
        )
    return path, ckpt


def read_training_checkpoint(
    path: str | Path, name: str = "ckpt", map_location: str = "cpu"
) -> tuple[Path, dict]:
    """:func:`read_checkpoint` of a file that must be a training checkpoint: a ``config`` with
    a ``model`` section and a ``state_dict`` of tensors.

    Raises:
        InputError: naming ``name``: as :func:`read_checkpoint`, or a bare state_dict (weights
            without a config), or a dict that is no checkpoint of this package.
    """
    path, ckpt = read_checkpoint(path, name, map_location)
    config, state = ckpt.get("config"), ckpt.get("state_dict")
    if state is None and ckpt and all(isinstance(v, torch.Tensor) for v in ckpt.values()):
        raise InputError(
            f"{name}: {path} is a bare state_dict (weights without the config that says which "
            "model they are); pass a checkpoint written by python -m granular_pyg.train"
        )
    if not isinstance(config, dict) or not isinstance(config.get("model"), dict):
        raise InputError(
            f"{name}: {path} is not a granular_pyg training checkpoint (no config with a model "
            "section); train one with python -m granular_pyg.train"
        )
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(
            f"{name}: {path} is not a granular_pyg training checkpoint (no state_dict of "
            "tensors); train one with python -m granular_pyg.train"
        )
    return path, ckpt
