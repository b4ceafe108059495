"""Benchmarks: ``python -m granular_pyg.bench suite=<name>`` (see ``conf/suite/``)."""
