"""The recipe that made each shipped model: ``python -m granular_pyg.train +experiment=<recipe>``.

A shipped checkpoint holds its config and weights, not the name of the recipe it was trained
with; this table records it, so that the docs (``docs/results.md``, pretrained models) and the
recipes in ``conf/experiment/`` can be checked against the shipped names
(``tests/test_docs.py``).
"""

from __future__ import annotations

__all__ = ["RECIPES"]

#: pretrained name -> the ``conf/experiment/<recipe>.yaml`` that trained it.
RECIPES = {
    "hopper": "general_hopper",  # 9,100 steps on the wedge families
    "drum": "drum_families",  # from general_drum's 3,000-step weights, 8,400 more steps
    # equivariant; then fine-tuned with offset noise (the recipe's comment has the commands)
    "fast_hopper": "equivariant_hopper",
    # equivariant; then fine-tuned with offset and drift noise and the reach mask (likewise)
    "fast_drum": "equivariant_drum",
}
