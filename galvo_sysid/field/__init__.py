"""Field work.

Bags, offline identification, simulate-to-bag, live record/replay/echo, plots, the demo.
"""
