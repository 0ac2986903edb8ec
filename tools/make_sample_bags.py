"""Generate the sample bags in bags/ (used by the README's examples and by the tests).

- ``bags/nominal``: the nominal scanner (Table I plant), 1 psi and 5 psi, 200 moves each
  (forward and back alternate): four complete windows of 100 moves, all OK.
- ``bags/drifting``: 1 psi, 600 moves while omega_1 falls 0.0025 % per move (1.5 % over the
  bag): six windows; the watchdog says OK, then WARN, then ERROR on omega_1.

Both are mcap with zstd-compressed chunks, written by ``galvo-sysid simulate`` (same code).

Usage::

    .venv/bin/python tools/make_sample_bags.py           # (re)write bags/
    .venv/bin/python tools/make_sample_bags.py --check   # compare bags/ with a fresh run
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from galvo_sysid.field.bags import BagReader
from galvo_sysid.field.simulate import simulate_bag

BAGS = Path(__file__).resolve().parents[1] / 'bags'

SAMPLES: dict[str, dict[str, object]] = {
    'nominal': {'angles': [0.3, 1.5], 'moves_per_angle': 200, 'seed': 1},
    'drifting': {'angles': [0.3], 'moves_per_angle': 600, 'seed': 2,
                 'drift': ['omega_1=-2.5e-5/move']},
}


def _make(directory: Path) -> None:
    for name, options in SAMPLES.items():
        summary = simulate_bag(directory / name, **options)  # type: ignore[arg-type]
        print(summary)


def _same(a: Path, b: Path) -> bool:
    with BagReader(a) as ra, BagReader(b) as rb:
        return [(m.topic, m.timestamp, m.data) for m in ra.raw_messages()] == \
               [(m.topic, m.timestamp, m.data) for m in rb.raw_messages()]


def main() -> int:
    """Write (or with --check, verify) the sample bags; return the exit code."""
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--check', action='store_true',
                        help='only check that bags/ matches what the simulator makes now')
    args = parser.parse_args()
    if args.check:
        with tempfile.TemporaryDirectory() as tmp:
            _make(Path(tmp))
            stale = [n for n in SAMPLES if not (BAGS / n).exists()
                     or not _same(BAGS / n, Path(tmp) / n)]
        if stale:
            print(f'stale sample bags: {", ".join(stale)} (run tools/make_sample_bags.py)')
            return 1
        print('sample bags are up to date')
        return 0
    BAGS.mkdir(exist_ok=True)
    for name in SAMPLES:
        shutil.rmtree(BAGS / name, ignore_errors=True)
    _make(BAGS)
    return 0


if __name__ == '__main__':
    sys.exit(main())
