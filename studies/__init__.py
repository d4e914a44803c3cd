"""One-off studies on real data (outside the installed package)."""
