"""Tracking (Chapter 4): the resolved-rate scheme that follows the constrained optimum along a path."""
