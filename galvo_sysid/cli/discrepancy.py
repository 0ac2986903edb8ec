"""``galvo-sysid discrepancy``: compare a plant model with the moves of a bag.

The subcommand's parser and run function; :mod:`galvo_sysid.cli.main` picks it up through its
``PLUGINS`` list (:func:`register`). Also runnable alone::

    python -m galvo_sysid.cli.discrepancy BAG [--model MODEL.yaml] [--json] [--report DIR]
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

from galvo_sysid import keep_freed_memory, limit_blas_threads
from galvo_sysid.cli.common import (
    HelpFormatter,
    Parser,
    check_output,
    finite_float,
    guarded,
    positive,
    print_json,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['add_parser', 'main', 'register', 'run']

_DESCRIPTION = """\
Compare a plant model with the moves recorded in a bag, find where they disagree, name the
missing physical effect, add it and show the gap shrink.

The comparison does not depend on the controller: the model is driven by each move's
measured current, from rest at the move's start angle, and its angle is compared with the
measured encoder. The gap is the RMS of the mean residual that the model leaves unexplained,
over all frequencies and target angles, in units of the noise floor that the move-to-move
scatter gives (0: the model explains the moves within the noise).

Candidate effects (the effect registry's), each fitted to the data and scored by the drop
of the Bayesian information criterion (the best one above --threshold that closes a quarter
of the gap, leaves a residual consistent with the noise where it acts and has plausible
parameters is added, then the search repeats):
{effects}

Every run ends in a verdict: named (the effects added explain the gap, with their
parameters), unexplained (a gap significant against the noise floor remains that no
library effect explains: where it sits in frequency, move phase and move size, and how
large it is) or consistent (the model explains the moves within the noise)."""

_EPILOG = """\
output:
  a summary (gap, where, candidates, the verdict in one sentence, effects found);
  --json prints one object {"verdict", "summary", "remaining": {"gap", "noise_gap",
  "significance", "where", ...}, "effect", "parameters", "gap_before", "gap_after",
  "candidates": [{"effect", "score", ...}], "steps": [...], "tried": [...],
  "proposal": {"terms", "gap_before", "gap_after", "share_closed", ...} or null, "where",
  "where_after", "moves", "angles", "threshold", "tolerance", "model"}.
  When the verdict is unexplained, a fallback fits the remaining residual with at most 3
  terms of a dictionary (functions of angle, velocity, acceleration and current on the
  current, or of the angle on the encoder reading): a proposal, never a name.
  --report DIR writes spectra.png, moves.png, candidates.png, where.png, summary.txt,
  result.json and model.yaml (the augmented model, loadable by --model), and
  proposal.yaml when there is a proposal (a model file with its proposed_terms effect).

examples:
  galvo-sysid simulate --out /tmp/fric --angles 0.1psi 1psi 10psi --moves-per-angle 40 \\
      --effect coulomb_friction:friction_current=0.02
  galvo-sysid discrepancy /tmp/fric
  galvo-sysid discrepancy /tmp/fric --json | jq .verdict,.effect
  galvo-sysid discrepancy /tmp/fric --report /tmp/fric_report --save-model fric.yaml
  galvo-sysid discrepancy /tmp/other --model fric.yaml

exit codes: 0 ok (whatever was found), 1 bad input, 2 usage error"""


def _description() -> str:
    """The help text with the registry's effects and their parameters."""
    from galvo_sysid.model.effects import EFFECTS

    lines = []
    for name, kind in EFFECTS.items():
        if not kind.candidate:
            continue
        params = ', '.join(f'{p.name} [{p.unit}]' if p.unit else p.name
                           for p in kind.parameters)
        lines.append(f'  {name:<21}{params}')
    return _DESCRIPTION.format(effects='\n'.join(lines))


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``discrepancy`` subcommand to an argparse subparsers object."""
    from galvo_sysid.discrepancy.settings import DEFAULT_THRESHOLD, DEFAULT_TOLERANCE
    from galvo_sysid.model.effects import CANDIDATE_NAMES

    p: argparse.ArgumentParser = subparsers.add_parser(
        'discrepancy', formatter_class=HelpFormatter, description=_description(),
        epilog=_EPILOG,
        help='where a plant model and a bag disagree, and which effect is missing')
    _arguments(p, DEFAULT_THRESHOLD, CANDIDATE_NAMES, DEFAULT_TOLERANCE)
    return p


def _arguments(p: argparse.ArgumentParser, threshold: float,
               effect_names: Sequence[str], tolerance: float) -> None:
    p.add_argument('bag', help='rosbag2 bag: directory, .mcap or .db3 file')
    p.add_argument('--model', metavar='MODEL.yaml',
                   help='plant model to compare with (default: the nominal model: Table I, '
                        'one sample of DSP delay, amplifier lag 0.6 tau)')
    p.add_argument('--json', action='store_true', help='print one JSON object on stdout')
    p.add_argument('--report', metavar='DIR',
                   help='write figures and files into DIR (new or empty, or with --force)')
    p.add_argument('--save-model', metavar='FILE',
                   help='write the augmented model (YAML) to FILE (not over an existing file '
                        'without --force)')
    p.add_argument('--force', action='store_true',
                   help='replace the --save-model file, and write into a --report directory '
                        'that holds files')
    p.add_argument('--threshold', type=finite_float, default=threshold, metavar='S',
                   help='score (BIC drop) a candidate needs to be accepted')
    p.add_argument('--tolerance', type=finite_float, default=tolerance, metavar='T',
                   help='after effects were named, a remaining gap up to T noise gaps still '
                        'counts as explained (verdict named); above it: unexplained')
    p.add_argument('--max-effects', type=positive(int), default=3, metavar='N',
                   help='most effects added in turn')
    p.add_argument('--effects', nargs='+', choices=list(effect_names), metavar='NAME',
                   default=list(effect_names), help='candidate effects to try')
    p.add_argument('--max-moves-per-angle', type=positive(int), default=None, metavar='N',
                   help='use at most N moves of each signed target angle (the first; '
                        'default: all)')
    p.add_argument('--measured-current', type=finite_float, default=None, metavar='LAG',
                   help="the bag's current is the coil current measured when the encoder is "
                        "read, behind the amplifier's lag LAG [s] (as `commission "
                        "--measured-current` found it): each move's current is made into the "
                        'held current that drives it')
    p.add_argument('--namespace', metavar='NS',
                   help='scanner namespace when the bag holds several (e.g. /left)')


def register(subparsers: Any) -> None:
    """Add the subcommand and set :func:`run` as its function (``galvo_sysid.cli.main`` plugin)."""
    add_parser(subparsers).set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the subcommand; return the exit code.

    Raises:
        GalvoSysidError: Bad bag, model or data (the caller prints one line).
    """
    from galvo_sysid.discrepancy.moves import read_moves
    from galvo_sysid.discrepancy.report import format_result, write_report
    from galvo_sysid.discrepancy.workflow import find_discrepancy
    from galvo_sysid.model.files import load_model, save_model

    if args.save_model:
        check_output(args.save_model, reads=args.bag, force=args.force, what='model file')
    if args.report:
        check_output(args.report, reads=args.bag, force=args.force, what='report directory',
                     directory=True)
    model = load_model(args.model)
    moves, rejected = read_moves(args.bag, namespace=args.namespace,
                                 max_moves_per_angle=args.max_moves_per_angle,
                                 measured_lag=args.measured_current)
    verbose = not args.json and sys.stderr.isatty()

    def progress(text: str) -> None:
        if verbose:
            sys.stderr.write(f'\r\033[Kdiscrepancy: {text}')
            sys.stderr.flush()

    try:
        result = find_discrepancy(moves, model, threshold=args.threshold,
                                  max_effects=args.max_effects, effects=args.effects,
                                  tolerance=args.tolerance,
                                  progress=progress)
    finally:
        if verbose:
            sys.stderr.write('\r\033[K')
    if args.json:
        print_json({**result.to_dict(), 'rejected': rejected})
    else:
        sys.stdout.write(format_result(result, source=str(args.bag)))
        if rejected:
            sys.stdout.write(f'set aside: {len(rejected)} move(s)/message(s) '
                             f'(see --json)\n')
    if args.save_model:
        path = save_model(result.final_model, args.save_model)
        print(f'discrepancy: augmented model written to {path}', file=sys.stderr)
    if args.report:
        files = write_report(result, args.report, source=str(args.bag))
        print(f'discrepancy: report written to {args.report} ({len(files)} files)',
              file=sys.stderr)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``discrepancy`` alone (``python -m galvo_sysid.cli.discrepancy``)."""
    limit_blas_threads()  # before numpy is imported
    keep_freed_memory()
    from galvo_sysid.discrepancy.settings import DEFAULT_THRESHOLD, DEFAULT_TOLERANCE
    from galvo_sysid.model.effects import CANDIDATE_NAMES

    parser = Parser(prog='galvo-sysid discrepancy', description=_description(),
                    epilog=_EPILOG, formatter_class=HelpFormatter)
    _arguments(parser, DEFAULT_THRESHOLD, CANDIDATE_NAMES, DEFAULT_TOLERANCE)
    args = parser.parse_args(argv)
    return guarded('galvo-sysid discrepancy', lambda: run(args))

if __name__ == '__main__':  # pragma: no cover
    sys.exit(main())
