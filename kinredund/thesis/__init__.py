"""Thesis examples, one module each: parameters from ``docs/thesis_readings.md`` and a ``reproduce`` entry."""
