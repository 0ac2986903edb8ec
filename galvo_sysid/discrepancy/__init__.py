"""The discrepancy workflow.

Where a model and measured moves disagree, and which physical effect is missing.
"""
