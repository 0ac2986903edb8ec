"""README's "Your own data": its Python example runs as printed, its limits are the code's."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

from galvo_sysid.field import importing
from galvo_sysid.ident import preprocess
from galvo_sysid.model import PAPER_MODEL

README = Path(__file__).resolve().parents[1] / 'README.md'


def section() -> str:
    text = README.read_text()
    start = text.index('## Your own data\n')
    return text[start:text.index('\n## ', start + 1)]


def test_the_python_example_runs_as_printed() -> None:
    blocks = re.findall(r'```python\n(.*?)```', section(), flags=re.DOTALL)
    assert len(blocks) == 1
    out = io.StringIO()
    namespace: dict[str, object] = {}
    with contextlib.redirect_stdout(out):
        exec(compile(blocks[0], 'README.md', 'exec'), namespace)
    printed = re.fullmatch(r'omega_1 = (\d+) \+- (\d+) rad/s\n', out.getvalue())
    assert printed, out.getvalue()
    assert float(printed[1]) == pytest.approx(PAPER_MODEL.modal.natural_frequencies[0],
                                              rel=1e-3)
    assert namespace['current'].shape == (100, 512)


def test_the_limits_it_states_are_the_code_s() -> None:
    text = ' '.join(section().split())
    low, high = importing.SAMPLE_PERIOD_RANGE
    assert (low, high) == (1e-7, 0.1)
    for words in (f'records under {importing.MIN_SAMPLES} samples',
                  'a sample period outside 1e-7..0.1 s',
                  f'beyond {preprocess.MAX_ANGLE:g} deg', '(1 GiB;'):
        assert words in text, words
    assert importing.MAX_BYTES == 1 << 30
    assert set(importing.CSV_COLUMNS) <= set(re.findall(r'`(\w+)`', text))
    assert set(importing.ARRAY_NAMES) <= set(re.findall(r'`(\w+)`', text))
