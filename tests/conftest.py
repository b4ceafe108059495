"""Shared pytest set-up."""

from __future__ import annotations

import os

import torch

# Tests are written for the 2-core reference machine; keep torch from oversubscribing.
torch.set_num_threads(min(2, os.cpu_count() or 1))
