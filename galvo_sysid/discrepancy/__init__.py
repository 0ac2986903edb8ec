"""The discrepancy workflow: where a plant model and measured moves disagree, and why.

One call of ``galvo-sysid discrepancy`` reads the moves of a bag (:mod:`.moves`), compares
the model, driven open loop by each move's measured current (:mod:`.plant`), with the
measured angle in units of the noise floor (:mod:`.compare`, on the spectra, gap and bands
of :mod:`.spectra`), fits and scores every candidate effect (:mod:`.candidates`), says where
the model disagrees by frequency, phase of the move and move size (:mod:`.localise`), adds
the best effects in turn (:mod:`.workflow`), proposes a few dictionary terms for a gap no
effect explains (:mod:`.fallback`) and writes the figures and text
(:mod:`.report`). The names below are the public API; the modules' underscored names are
private to the subpackage.
"""

from galvo_sysid.discrepancy.candidates import CandidateFit
from galvo_sysid.discrepancy.compare import Comparison, Diagnostics
from galvo_sysid.discrepancy.fallback import Proposal, ProposedTerm, propose
from galvo_sysid.discrepancy.localise import Band, Localisation, localise
from galvo_sysid.discrepancy.moves import MoveSet, read_moves
from galvo_sysid.discrepancy.plant import PlantSimulator
from galvo_sysid.discrepancy.report import format_result, write_report
from galvo_sysid.discrepancy.workflow import (
    DEFAULT_THRESHOLD,
    DiscrepancyResult,
    Step,
    find_discrepancy,
)

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
