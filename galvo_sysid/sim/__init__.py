"""The closed-loop scanner simulator.

Controller design, move profiles, the loop.
"""
