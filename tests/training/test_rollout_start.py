"""Where a validation rollout starts: with ``start="event"``, from the initial states whose
first learned step holds the trajectory's first wall event (the lid's removal), so that a model
that never lets a bed at rest go shows in validation."""

from __future__ import annotations

import pytest
import torch

from granular_pyg.errors import InputError
from granular_pyg.inference import initial_frames
from granular_pyg.io import read_trajectory
from granular_pyg.nn import Processor
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.training.callbacks import RolloutValidation


def _sim(dt: float, history: int = 5) -> LearnedSimulator:
    torch.manual_seed(0)
    proc = Processor(latent=16, num_steps=1, aggr="mean")
    return LearnedSimulator(proc, radius=0.0075, latent=16, dt=dt, history=history)


@pytest.fixture(scope="module")
def hopper():
    return read_trajectory(sample_files("hopper")[0])  # 2.5 ms frames, lid removed at 0.02 s


def test_the_first_frame_unless_asked(hopper):
    assert RolloutValidation().start_frame(_sim(hopper.frame_dt), hopper) == 0


def test_the_lid_is_removed_in_the_first_step_one_frame_per_step(hopper):
    # H = 5, k = 1: the last initial state is the frame of the removal (0.02 s, frame 8): the
    # lid is gone over the first step, so the bed's release is the first prediction
    assert RolloutValidation(start="event").start_frame(_sim(hopper.frame_dt), hopper) == 3


@pytest.mark.parametrize("k, history", [(1, 3), (2, 2), (3, 2), (4, 1)])
def test_the_first_step_holds_the_event(hopper, k, history):
    sim = _sim(k * hopper.frame_dt, history)
    start = RolloutValidation(start="event").start_frame(sim, hopper)
    _, initial = initial_frames(sim, hopper, start)
    t_last, event = float(hopper.times[initial[-1]]), WallSet(hopper.scene).event_times()[0]
    assert t_last <= event + 1e-12 < t_last + float(sim.dt)
    if k > 1:  # strictly inside: the removal falls within the step, not at its end
        assert t_last < event < t_last + float(sim.dt) - 1e-9


def test_no_later_event_starts_at_the_first_frame(hopper):
    # H = 5, k = 2: the earliest last initial state (0.025 s) is already after the removal
    assert RolloutValidation(start="event").start_frame(_sim(2 * hopper.frame_dt), hopper) == 0


def test_an_unknown_start_is_refused():
    with pytest.raises(InputError, match=r"rollout_validation\.start"):
        RolloutValidation(start="lid")
