"""One-off tools that live beside the package, not in it (they need outside checkouts).

Run them from the checkout's root: ``python -m tools.<name> --help``.
"""
