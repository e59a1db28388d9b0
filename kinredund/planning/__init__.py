"""Off-line trajectory planning with collision avoidance (Chapter 6)."""
