"""``galvo-sysid simulate``: write a bag from the simulated scanner (fast, no ROS)."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

from galvo_sysid.cli.common import (
    add_subcommand,
    bounded_int,
    dither_amplitude,
    nonnegative_int,
    parse_angle,
    positive,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['LIMITS', 'add_parser', 'angles', 'run']

LIMITS = {'moves_per_angle': (2, 1_000_000), 'seed': (0, 2**31 - 1)}
"""The ranges of --moves-per-angle and --seed: those of the galvo_driver's parameters
(galvo_sysid.field.simulate.schedule_limits(), written out so that building the parser loads no
numpy; a test checks the two agree)."""

_DESCRIPTION = (
    "Run the closed-loop simulator (the plant of a model file, by default the paper's\n"
    'scanner of Table I; DSP delay + amplifier lag, quantised encoder, coloured\n'
    'noise, a positioning controller designed from the model) and write its moves\n'
    'into a rosbag2 bag: topics /galvo/current and /galvo/encoder (MoveSamples), the\n'
    'same messages the galvo_driver node publishes, with header stamps and log times\n'
    'in simulated time (starting at 0). No ROS graph is used: it runs as fast as the\n'
    'simulator. For each angle the scanner moves forward (+angle) and back (-angle)\n'
    'in turn, so --moves-per-angle 200 gives 100 moves of each sign: one window each.')

_EPILOG = (
    'examples:\n'
    '  galvo-sysid simulate --out /tmp/nominal --angles 1psi --moves-per-angle 200\n'
    '  galvo-sysid simulate --out /tmp/paper --angles paper --moves-per-angle 200\n'
    '  galvo-sysid simulate --out /tmp/drift --angles 1psi --moves-per-angle 1000 \\\n'
    '      --drift omega_1=-2e-5/move\n'
    '  galvo-sysid simulate --out /tmp/step --angles 1psi 3psi --moves-per-angle 400 \\\n'
    '      --step k0=0.97@400 --effect coulomb_friction:friction_current=0.01\n'
    '  galvo-sysid simulate --out /tmp/long --angles 1psi --record-length 1024 \\\n'
    '      --model galvo_sysid/model/data/paper_table1.yaml   # from a source checkout')


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``simulate`` subcommand to an argparse subparsers object."""
    p = add_subcommand(
        subparsers, 'simulate', help='write a bag from the simulated scanner (fast, no ROS)',
        description=_DESCRIPTION, epilog=_EPILOG)
    p.add_argument('--out', required=True, metavar='BAG',
                   help='bag directory to create (it appears when complete: a failed run '
                        'leaves nothing)')
    p.add_argument('--angles', nargs='+', default=['1psi'], metavar='ANGLE',
                   help="target angles [deg]; '2psi' = 2 x 0.3 deg; 'paper' = the paper's 19")
    p.add_argument('--moves-per-angle', type=bounded_int(*LIMITS['moves_per_angle']),
                   default=200, metavar='N',
                   help='moves per angle, even (forward and back alternate; at most '
                        f"{LIMITS['moves_per_angle'][1]:,})")
    p.add_argument('--seed', type=bounded_int(*LIMITS['seed']), default=0,
                   help='noise seed (same seed, same bag)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='rosbag2 storage format')
    p.add_argument('--model', metavar='FILE', default=None,
                   help="plant-model file of the scanner (default: the packaged model of the "
                        "paper's scanner); sets the sample period, record and dwell lengths")
    p.add_argument('--record-length', type=positive(int), default=None, metavar='N',
                   help="recorded samples per move (default: the model's)")
    p.add_argument('--dwell-length', type=nonnegative_int, default=None, metavar='N',
                   help="samples between a record's end and the next move (default: the "
                        "model's)")
    p.add_argument('--drift', action='append', default=[], metavar='PARAM=RATE/UNIT[@START]',
                   help='a parameter drifting: relative change per second (/s) or per move '
                        '(/move) from START on (same unit, default 0), e.g. '
                        'omega_1=-2e-5/move or k0=-0.001/s@2 (k0, k1.., omega_1.., zeta_1.., '
                        'lag_time_constant, ...); repeatable')
    p.add_argument('--step', action='append', default=[], metavar='PARAM=FACTOR@WHEN',
                   help='a parameter multiplied by FACTOR from move WHEN on (or from WHEN '
                        'seconds: @1.5s), e.g. k0=0.9@400; repeatable')
    p.add_argument('--effect', action='append', default=[], metavar='NAME[:K=V,...]',
                   help='add a physical effect the reference model lacks (see the '
                        'simulator docs), e.g. coulomb_friction:friction_current=0.05')
    p.add_argument('--dither', type=dither_amplitude, default=0.0, metavar='AMPLITUDE',
                   help="tones of this amplitude [A, or e.g. 10mA] at the model's resonances "
                        "added to every move's current command (as the driver's "
                        'dither.amplitude; galvo-sysid plan says what a dither buys and costs)')
    p.add_argument('--dither-modes', default='all', metavar='MODES',
                   help="the resonances the dither tones sit at: 'all' or mode numbers, "
                        "comma-separated, e.g. 3 (default: all)")
    return p


def run(args: argparse.Namespace) -> int:
    """Write the bag; its summary goes to stderr. Return the exit code.

    Raises:
        GalvoSysidError: Bad option value or model, output bag exists (the caller prints one
            line).
    """
    from galvo_sysid.field.simulate import simulate_bag
    from galvo_sysid.model import load_model
    from galvo_sysid.sim.config import SimulatorConfig
    from galvo_sysid.sim.dither import dither_for_modes

    model = load_model(args.model or None)
    config = SimulatorConfig(plant=model, record_length=args.record_length,
                             dwell_length=args.dwell_length,
                             dither=dither_for_modes(args.dither, args.dither_modes, model=model))
    summary = simulate_bag(args.out, angles=angles(args.angles),
                           moves_per_angle=args.moves_per_angle, seed=args.seed,
                           storage=args.storage, drift=args.drift, steps=args.step,
                           effects=args.effect, config=config, model_path=args.model or '')
    print(summary, file=sys.stderr)
    return 0


def angles(items: Sequence[str]) -> list[float]:
    """The target angles of ``--angles``: ``'paper'`` expands to the paper's 19.

    Raises:
        ConfigurationError: An item is not an angle.
    """
    from galvo_sysid.model import PAPER_ANGLES

    found: list[float] = []
    for item in items:
        if item.lower() == 'paper':
            found.extend(PAPER_ANGLES)
        else:
            try:
                found.append(parse_angle(item))
            except argparse.ArgumentTypeError as err:
                from galvo_sysid.errors import ConfigurationError

                raise ConfigurationError(str(err)) from None
    return found
