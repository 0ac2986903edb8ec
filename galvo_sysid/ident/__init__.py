"""Identification numerics, no I/O.

Filters, ARX, delay, preprocessing, modal decomposition, the paper pipeline, the refined
fit and the identify entry point.
"""
