"""The report: figures, summary, JSON and the augmented model."""

from __future__ import annotations

import json
import math
from dataclasses import replace

from discrepancy_cases import CASES, analysed, hidden_effects

from galvo_sysid.model import load_model


def test_report_files(tmp_path):
    from galvo_sysid.discrepancy.report import format_result, write_report

    result = analysed(hidden_effects(CASES[5][:2]), seed=105)
    files = write_report(result, tmp_path / 'rep', source='friction.mcap')
    names = {f.name for f in files}
    assert names == {'spectra.png', 'moves.png', 'candidates.png', 'where.png', 'summary.txt',
                     'result.json', 'model.yaml'}
    for f in files:
        assert f.stat().st_size > 100, f
    assert (tmp_path / 'rep' / 'spectra.png').read_bytes()[:4] == b'\x89PNG'
    assert load_model(tmp_path / 'rep' / 'model.yaml') == result.final_model
    summary = format_result(result, source='friction.mcap')
    assert 'found: coulomb_friction' in summary
    assert json.loads((tmp_path / 'rep' / 'result.json').read_text())['effect'] == \
        'coulomb_friction'
    # a share left that is not a number (nothing to leave where it acts) is a dash, not 'inf %'
    acting = next(c for c in result.candidates if c.effect != 'none')
    odd = replace(result, candidates=tuple(replace(c, local_left=math.inf) if c is acting else c
                                           for c in result.candidates))
    text = format_result(odd, source='friction.mcap')
    assert 'inf %' not in text
    assert 'left     -   ' in text
