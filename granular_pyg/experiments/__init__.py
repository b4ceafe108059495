"""Small experiments from the paper's appendices (``python -m granular_pyg.experiments.<name>``)."""
