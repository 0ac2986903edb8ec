"""Identification numerics, no I/O.

Filters, ARX, delay, preprocessing, modal decomposition, the paper pipeline (``paper``), the
refined fit (``refine/``), the entry points (``identify``), pooling (``pool``), what they
return (``result``) and commissioning (``commission``). The public API:
"""

from galvo_sysid.ident.commission import Commissioning, commission
from galvo_sysid.ident.identify import METHODS, identify_joint, identify_window
from galvo_sysid.ident.pool import pool_results
from galvo_sysid.ident.result import IdentificationResult

__all__ = [
    'METHODS',
    'Commissioning',
    'IdentificationResult',
    'commission',
    'identify_joint',
    'identify_window',
    'pool_results',
]
