"""The identification methods, by name.

What ``method`` of the sysid node and of ``galvo-sysid identify`` takes; no heavy imports
(the node parameters' list reads it in every process).
"""

from __future__ import annotations

__all__ = ['METHODS']

METHODS = ('refined', 'paper-A', 'paper-B')
"""Methods :func:`~galvo_sysid.ident.identify.identify_window` accepts: the refined fit
(``refine/``) and the paper's pipeline, windows averaged (A) or concatenated (B)."""
