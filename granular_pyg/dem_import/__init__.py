"""Importing a user's own LIGGGHTS runs: dumps, STL walls, input script or log, mesh dumps and
``walls.yaml`` -> a Trajectory with its Scene (``python -m granular_pyg.dem_import.convert``).

Running LIGGGHTS on a Scene is :mod:`granular_pyg.dem`; the two share only its dump parser
(:mod:`granular_pyg.dem.dump`).
"""
