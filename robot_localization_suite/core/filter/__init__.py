"""Pieces every filtering method shares: particle utilities and the scan-to-map refinement's solver."""
