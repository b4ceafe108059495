"""tools.rest_stiffness: a shipped model's answer to particles held displaced at rest."""

from __future__ import annotations

import math
import re

from tools.rest_stiffness import DELTAS_M, SPEEDS_M_S, main


def test_it_prints_the_bias_and_a_finite_change_per_displacement_and_per_speed(capsys):
    main(["pretrained:fast_hopper", "sample:hopper"])
    lines = capsys.readouterr().out.splitlines()
    assert re.search(r"bias a_z [+-]\d+\.\d{3} m/s\^2", lines[0])
    tenths = [float(v) for v in lines[1].split(":")[1].split()]
    assert lines[1].strip().startswith("bias by height tenth") and len(tenths) == 10
    for name, line in zip(("lowest", "middle"), lines[2:4], strict=True):
        assert line.strip().startswith(name)
        changes = [float(v) for v in re.findall(r"mm: ([+-]\d+\.\d+)", line)]
        assert len(changes) == len(DELTAS_M) and all(math.isfinite(c) for c in changes)
    for label, line in zip(("moving along z", "last step along z"), lines[4:], strict=True):
        assert line.strip().startswith("whole bed") and label in line
        changes = [float(v) for v in re.findall(r"mm/s: ([+-]\d+\.\d+)", line)]
        assert len(changes) == len(SPEEDS_M_S) and all(math.isfinite(c) for c in changes)
