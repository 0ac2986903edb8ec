"""The discrepancy workflow's defaults and verdicts.

No heavy imports: the command line's parser reads them for its help in every
``galvo-sysid`` process, without loading the workflow's numerics (:mod:`scipy.optimize`).
"""

from __future__ import annotations

__all__ = ['DEFAULT_THRESHOLD', 'DEFAULT_TOLERANCE', 'VERDICTS']

DEFAULT_THRESHOLD = 10.0
"""Score (BIC drop) a candidate needs to be accepted."""

DEFAULT_TOLERANCE = 2.0
"""After effects were named, the remaining gap up to this many noise gaps still counts as
explained (a model of an effect is rarely exact: Coulomb friction's stick-slip leaves up to
about 1.5 noise gaps); above it the verdict is ``unexplained``."""

VERDICTS = ('named', 'unexplained', 'consistent')
"""How every run ends: effects named that explain the gap; a significant gap that no
library effect explains; or a model that explains the moves within the noise."""
