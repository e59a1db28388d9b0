"""Thesis examples, one module each: parameters from ``../shared/thesis/NOTES.md`` and a ``reproduce`` entry."""
