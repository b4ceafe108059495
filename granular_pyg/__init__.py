"""granular_pyg."""
