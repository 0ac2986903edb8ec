"""Identification numerics, no I/O.

ARX, delay, preprocessing, modal decomposition, the paper pipeline (``paper``), the refined
fit (``refine/``), the method names (``methods``), the entry points (``identify``), pooling
(``pool``), what they return (``result``) and commissioning (``commission``).

The names below are loaded when first used, so that importing one light module (say
:mod:`~galvo_sysid.ident.methods`, which the node parameters read in every process) does not
import the fits and :mod:`scipy.optimize` with them. The public API:
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from galvo_sysid import lazy_names

if TYPE_CHECKING:
    from galvo_sysid.ident.commission import Commissioning, commission
    from galvo_sysid.ident.identify import identify_joint, identify_window
    from galvo_sysid.ident.methods import METHODS
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

_WHERE = {
    'METHODS': 'methods', 'Commissioning': 'commission', 'IdentificationResult': 'result',
    'commission': 'commission', 'identify_joint': 'identify', 'identify_window': 'identify',
    'pool_results': 'pool',
}


__getattr__ = lazy_names(__name__, _WHERE)
