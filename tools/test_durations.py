r"""Write ``test/durations.json``: each test module's time in a run of the suite.

``make test`` hands whole modules to its two pytest-xdist workers; ``test/conftest.py`` hands
out the longest first (by this file), so that neither worker is left alone with a long module
at the end. A module missing from the file (a new one) counts as 0 s and goes last; a stale
file costs only balance, never a result. Refresh it after a run that wrote a JUnit report::

    .venv/bin/python -m pytest -q -n 2 --dist loadscope test --junitxml=/tmp/junit.xml
    .venv/bin/python tools/test_durations.py /tmp/junit.xml

Only the standard library is used.
"""

from __future__ import annotations

import argparse
import json
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / 'test' / 'durations.json'


def module_seconds(junit: Path) -> dict[str, float]:
    """Seconds per test module (``test/x/test_y.py``: set-up, call and tear-down summed)."""
    totals: dict[str, float] = defaultdict(float)
    for case in ET.parse(junit).iter('testcase'):
        parts = []
        for part in case.get('classname', '').split('.'):
            parts.append(part)
            if part.startswith('test_'):
                break
        totals['/'.join(parts) + '.py'] += float(case.get('time', '0'))
    return {name: round(seconds, 1) for name, seconds in
            sorted(totals.items(), key=lambda item: -item[1])}


def main(argv: list[str] | None = None) -> int:
    """Read a JUnit report and write the modules' seconds."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n', 1)[0])
    parser.add_argument('junit', type=Path, help='the report of `pytest --junitxml`')
    parser.add_argument('--out', type=Path, default=OUT, help=f'default {OUT}')
    args = parser.parse_args(argv)
    try:
        seconds = module_seconds(args.junit)
    except (OSError, ET.ParseError, ValueError) as exc:  # ValueError: a time not a number
        print(f'error: cannot read {args.junit}: {exc}', file=sys.stderr)
        return 1
    if not seconds:
        print(f'error: {args.junit} has no test cases', file=sys.stderr)
        return 1
    args.out.write_text(json.dumps(seconds, indent=0) + '\n', encoding='utf-8')
    print(f'{len(seconds)} modules, {sum(seconds.values()):.0f} s, written to {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
