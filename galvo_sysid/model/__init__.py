"""What the scanner is.

The modal model, its input dynamics, the physical effects and the plant-model file.
"""
