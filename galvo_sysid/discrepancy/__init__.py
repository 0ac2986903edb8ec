"""The discrepancy workflow: where a plant model and measured moves disagree, and why.

One call of ``galvo-sysid discrepancy`` reads the moves of a bag (:mod:`.moves`), compares
the model, driven open loop by each move's measured current (:mod:`.plant`), with the
measured angle in units of the noise floor (:mod:`.compare`, on the spectra, gap and bands
of :mod:`.spectra`), fits and scores every candidate effect (:mod:`.candidates`), says where
the model disagrees by frequency, phase of the move and move size (:mod:`.localise`), adds
the best effects in turn (:mod:`.workflow`), proposes a few dictionary terms for a gap no
effect explains (:mod:`.fallback`) and writes the figures and text
(:mod:`.report`); its defaults are in :mod:`.settings`. The names below are the public
API, loaded when first used (the command line's help reads :mod:`.settings` without the
numerics); the modules' underscored names are private to the subpackage.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from galvo_sysid import lazy_names

if TYPE_CHECKING:
    from galvo_sysid.discrepancy.candidates import CandidateFit
    from galvo_sysid.discrepancy.compare import Comparison, Diagnostics
    from galvo_sysid.discrepancy.fallback import Proposal, ProposedTerm, propose
    from galvo_sysid.discrepancy.localise import Band, Localisation, localise
    from galvo_sysid.discrepancy.moves import MoveSet, read_moves
    from galvo_sysid.discrepancy.plant import PlantSimulator
    from galvo_sysid.discrepancy.report import format_result, write_report
    from galvo_sysid.discrepancy.settings import DEFAULT_THRESHOLD
    from galvo_sysid.discrepancy.workflow import DiscrepancyResult, Step, find_discrepancy

__all__ = [
    'DEFAULT_THRESHOLD',
    'Band',
    'CandidateFit',
    'Comparison',
    'Diagnostics',
    'DiscrepancyResult',
    'Localisation',
    'MoveSet',
    'PlantSimulator',
    'Proposal',
    'ProposedTerm',
    'Step',
    'find_discrepancy',
    'format_result',
    'localise',
    'propose',
    'read_moves',
    'write_report',
]

_WHERE = {
    'DEFAULT_THRESHOLD': 'settings',
    'Band': 'localise',
    'CandidateFit': 'candidates',
    'Comparison': 'compare',
    'Diagnostics': 'compare',
    'DiscrepancyResult': 'workflow',
    'Localisation': 'localise',
    'MoveSet': 'moves',
    'PlantSimulator': 'plant',
    'Proposal': 'fallback',
    'ProposedTerm': 'fallback',
    'Step': 'workflow',
    'find_discrepancy': 'workflow',
    'format_result': 'report',
    'localise': 'localise',
    'propose': 'fallback',
    'read_moves': 'moves',
    'write_report': 'report',
}


__getattr__ = lazy_names(__name__, _WHERE)
