"""``galvo-sysid identify``: identify the plant from a bag, offline (no ROS).

Also the readable report it prints (:func:`format_identification`).
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import TYPE_CHECKING, Any

from galvo_sysid.cli.common import BAG_HELP, Progress, add_subcommand, positive, print_json

if TYPE_CHECKING:
    from galvo_sysid.field.results import BagIdentification

__all__ = ['add_parser', 'format_identification', 'run']

_DESCRIPTION = (
    'Identify the scanner from a bag with the same code as the sysid node (so the\n'
    'numbers are its numbers; with the warm start each refined fit starts from the\n'
    'window two before it, the node from the previous window of the angle, which\n'
    'moves an estimate by a fraction of its std): current and encoder messages are\n'
    'paired by move_id, grouped by signed target angle into windows of --window-size\n'
    'moves, each window is fitted (--method) and judged for drift like the watchdog\n'
    'node does. At the end of the bag, an unfinished window holding at least half a\n'
    'window is fitted too and marked partial. Moves that cannot be used (NaN,\n'
    'unpaired, duplicate move_id, wrong length, zero angle, ...) are listed as\n'
    'rejected with the reason; the rest is used.\n\n'
    "The scanner is the plant-model file of --model (default: the paper's scanner):\n"
    'its modes, bands, input dynamics and sample period are what is identified, and\n'
    'deviations are shown from it. Data that do not match it (another sample period,\n'
    'a mode outside its band, a residual far above the noise) are said so in one\n'
    'line: the scanner is another one (galvo-sysid commission makes its model).\n\n'
    'methods: refined  structured output-error fit of the modal model (default)\n'
    '         paper-A  the paper: average the moves, fictitious input, ARX(15,15)\n'
    '         paper-B  the paper: concatenate the moves instead of averaging')

_EPILOG = (
    'output:\n'
    '  a table of the windows (deviation of each parameter from the reference [%],\n'
    '  drift level), the pooled estimate with standard deviations, the rejected moves.\n'
    '  --json prints one object {"windows": [...], "pooled": {...}, "rejected": [...]}\n'
    '  whose window fields are named as in ModalParameters, plus "partial" and\n'
    '  "drift" (level OK/WARN/ERROR/MISMATCH and deviations); "pooled" also says\n'
    '  "pooling" (joint or inverse-variance), "pooled_windows" and "pooling_note"\n'
    '  (why the joint fit was not used, else null); "model" names the model file,\n'
    '  "model_mismatch" why the data do not match it (else null) and\n'
    '  "mismatched_windows" the windows concerned.\n'
    '  Exit code 1 when no window was identified (e.g. none matches the model).\n\n'
    'examples:\n'
    '  galvo-sysid identify bags/nominal\n'
    "  galvo-sysid identify bags/drifting --json | jq '.windows[].drift.level'\n"
    '  galvo-sysid identify run.mcap --method paper-A --plot bode.png\n'
    '  galvo-sysid identify field2 --model scanner2.yaml\n'
    '  galvo-sysid identify field1 --sysid-params config/sysid.yaml \\\n'
    '      --watchdog-params config/watchdog.yaml   # as the deployed nodes are set')


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``identify`` subcommand to an argparse subparsers object."""
    p = add_subcommand(
        subparsers, 'identify', help='identify the plant from a bag, offline (no ROS)',
        description=_DESCRIPTION, epilog=_EPILOG)
    p.add_argument('bag', help=BAG_HELP)
    p.add_argument('--json', action='store_true', help='print one JSON object on stdout')
    # The choices and defaults below are galvo_sysid.ident.methods.METHODS,
    # galvo_sysid.field.pooling.POOLINGS and defaults('sysid') of galvo_sysid.monitor.parameters
    # written out (test/cli/test_cli.py checks them): importing those modules here would load
    # numpy and scipy for every subcommand's parser (half a second of start-up for `info`).
    p.add_argument('--method', choices=('refined', 'paper-A', 'paper-B'), default=None,
                   help="identification method (default: the sysid node's, refined)")
    p.add_argument('--plot', metavar='FILE',
                   help='also write a plot (.png, .pdf or .svg): measured frequency response '
                        'of the averaged moves with coherence against the identified and '
                        'reference models, and each parameter over time with the WARN and '
                        'tolerance bands')
    p.add_argument('--absolute', action='store_true',
                   help="also print each window's identified values (with units) beside "
                        'the deviations')
    p.add_argument('--window-size', type=positive(int), default=None, metavar='N',
                   help='moves per window (default: the sysid node parameter window_size, '
                        '100)')
    p.add_argument('--min-partial', type=positive(int), default=None, metavar='N',
                   help='smallest unfinished window fitted at the end (default: half a window)')
    p.add_argument('--namespace', metavar='NS',
                   help='scanner namespace when the bag holds several (e.g. /left)')
    p.add_argument('--na', type=positive(int), default=None, metavar='N',
                   help='ARX order of A[q] (paper pipeline; start of the refined fit); default: '
                        'the sysid node parameter na, 15')
    p.add_argument('--nb', type=positive(int), default=None, metavar='N',
                   help='ARX order of B[q]; default: the sysid node parameter nb, 15')
    p.add_argument('--measured-current', type=float, default=None, metavar='LAG',
                   help="the bag's current is the coil current measured when the encoder is "
                        "read, behind the amplifier's lag LAG [s] (as `commission "
                        "--measured-current` found it): each window's current is made into "
                        'the held current that drives it')
    p.add_argument('--model', metavar='FILE', default=None,
                   help="plant-model file of the scanner (default: the sysid parameter model, "
                        "else the packaged model of the paper's scanner)")
    p.add_argument('--sysid-params', metavar='YAML',
                   help="the sysid node's --params-file (e.g. config/sysid.yaml): model, "
                        'window and pairing settings, method, na, nb, warm_start; options '
                        'given here win')
    p.add_argument('--watchdog-params', metavar='YAML',
                   help="the watchdog node's --params-file (e.g. config/watchdog.yaml): "
                        'reference model (its model; "" = the packaged paper model, as the '
                        'node) and tolerances of the drift verdicts (default: the reference '
                        'is the --model)')
    p.add_argument('--jobs', type=positive(int), default=None, metavar='N',
                   help='windows fitted in parallel (default and most: one per CPU, fewer '
                        'when memory is short); the numbers do not depend on it')
    p.add_argument('--no-warm-start', dest='warm_start', action='store_false', default=None,
                   help='fit every window afresh (default: as the sysid parameter warm_start, '
                        'true: a refined fit starts from the window two before it, about 40 %% '
                        'faster, as accurate; two fits at a time)')
    p.add_argument('--pooling', choices=('joint', 'inverse-variance'), default=None,
                   help='pooled estimate: one joint fit to all windows (default for refined; '
                        'sharpest) or the inverse-variance combination of the windows '
                        '(default and only choice for the paper methods)')
    return p


def run(args: argparse.Namespace) -> int:
    """Identify the bag; print the table (or ``--json``); return the exit code.

    Raises:
        GalvoSysidError: Bad bag, model or parameter file (the caller prints one line).
    """
    from galvo_sysid.field.jobs import job_limit
    from galvo_sysid.field.offline import identify_bag
    from galvo_sysid.field.parameter_file import load_node_parameters
    from galvo_sysid.monitor.reference import monitor_from_parameters

    if args.plot:  # say a bad file name before the work, not after
        from galvo_sysid.field.plots import check_plot_path

        check_plot_path(args.plot)
    from galvo_sysid.model import load_model
    from galvo_sysid.monitor.parameters import defaults
    from galvo_sysid.monitor.tasks import mismatch_message

    sysid = defaults('sysid')  # the sysid node's defaults, then its parameter file, then options
    if args.sysid_params:
        sysid.update(load_node_parameters(args.sysid_params, 'sysid'))
    for name in ('window_size', 'method', 'na', 'nb', 'model', 'warm_start'):
        if getattr(args, name) is not None:
            sysid[name] = getattr(args, name)
    if args.measured_current is not None:  # as the sysid parameters current, its lag
        sysid['current'], sysid['measured_current_lag'] = 'measured', args.measured_current
    model_path = sysid['model'] or ''
    if not isinstance(model_path, str):
        from galvo_sysid.errors import ConfigurationError

        msg = f'sysid parameter model must be a file name, got {model_path!r}'
        raise ConfigurationError(msg)
    model = load_model(model_path or None)
    monitor = None
    if args.watchdog_params:
        monitor = monitor_from_parameters(load_node_parameters(args.watchdog_params,
                                                               'watchdog'))
    limit, why = job_limit()  # one process per CPU, as memory allows
    if args.jobs is not None and args.jobs > limit:
        print(f'identify: --jobs {args.jobs}: {limit} process(es) at most here ({why})',
              file=sys.stderr)
    progress = Progress(sys.stderr, 'identify', enabled=not args.json)
    try:
        found = identify_bag(args.bag, method=str(sysid['method']),
                             window_size=int(sysid['window_size']),
                             min_partial=args.min_partial, namespace=args.namespace,
                             monitor=monitor, na=int(sysid['na']), nb=int(sysid['nb']),
                             windower=sysid, jobs=min(args.jobs or limit, limit),
                             pooling=args.pooling, model=model, model_path=model_path,
                             progress=progress, response_windows=16 if args.plot else 0,
                             warm_start=bool(sysid['warm_start']),
                             measured_lag=(sysid['measured_current_lag']
                                           if sysid['current'] == 'measured' else None))
    finally:
        progress.close()
    if args.json:
        print_json(found.to_dict())
    else:
        sys.stdout.write(format_identification(found, absolute=args.absolute))
    if args.plot and not found.windows:
        print(f'identify: no plot written to {args.plot}: no window identified',
              file=sys.stderr)
    elif args.plot:
        from galvo_sysid.field.plots import save_identification_plot

        path = save_identification_plot(found, args.plot)
        print(f'identify: plot written to {path}', file=sys.stderr)
    if found.model_mismatch is not None:  # one plain line: another scanner, not drift
        print(mismatch_message(found.model_mismatch, model_path=found.model), file=sys.stderr)
        return 0 if found.windows else 1
    if not found.windows:
        print(f'identify: no window identified in {args.bag} (need at least '
              f'{args.min_partial or found.window_size // 2} usable moves of one target angle)',
              file=sys.stderr)
        return 1
    return 0


def format_identification(found: BagIdentification, *, absolute: bool = False) -> str:
    """The readable report ``identify`` prints without ``--json``.

    With ``absolute``, a second table gives each window's identified values (units in the
    header) beside the deviations.
    """
    from galvo_sysid.model import REFERENCE_MODEL, model_label, parameter_unit

    reference = found.reference if found.reference is not None else REFERENCE_MODEL
    ref = reference.parameters()
    ref_name = found.reference_name or model_label(None)
    names = list(ref)
    info = found.info
    span = (info.end - info.start) * 1e-9
    lines = [f'bag: {info.path} ({info.storage}), {found.moves:g} moves, {span:.2f} s; '
             f'method {found.method}, windows of {found.window_size} moves; model '
             f'{found.model_name}'
             + ('' if found.measured_lag is None else
                f'; current: measured, made held with an amplifier lag of '
                f'{found.measured_lag:.6g} s'),
             *(f'note: {claim}' for claim in info.claims),
             '']

    def dev(values: dict[str, float], name: str) -> float:
        return 100 * (values.get(name, math.nan) - ref[name]) / ref[name]

    if found.windows:
        lines.append(f'deviation from the reference model {ref_name} [%]:')
        head = f'{"win":>4} {"angle":>8} {"moves":>5} {"fit%":>6} ' + ' '.join(
            f'{n:>8}' for n in names) + '  drift'
        lines.append(head)
        unresolved_seen = False
        for w in found.windows:
            values = w.result.model.parameters()
            unresolved = {f'{p}{i}' for i, r in enumerate(w.result.resolved, start=1)
                          if not r for p in ('k', 'omega_', 'zeta_')}
            unresolved_seen |= bool(unresolved & set(names))
            devs = ' '.join(f'{"unres.":>8}' if n in unresolved else f'{dev(values, n):8.3f}'
                            for n in names)
            mark = '*' if w.partial else ' '
            lines.append(f'{w.window_index:>4} {w.target_angle:+8.3f} {w.result.moves:>4}{mark} '
                         f'{w.result.fit_percent:6.2f} {devs}  {w.drift.level_name}')
        if any(w.partial for w in found.windows):
            lines.append('  * partial window (end of bag)')
        if unresolved_seen:
            lines.append("  unres.: a mode the window's data do not resolve (not judged)")
        lines.append('')
        if absolute:
            lines.append('identified values (unresolved modes in parentheses):')
            lines.append(f'{"win":>4} {"angle":>8} ' + ' '.join(f'{n:>13}' for n in names))
            lines.append(f'{"":>4} {"[deg]":>8} ' + ' '.join(
                f'{"[" + parameter_unit(n) + "]":>13}' for n in names))
            lines.append(f'{"ref":>4} {"":>8} ' + ' '.join(f'{ref[n]:13.6g}' for n in names))
            for w in found.windows:
                values = w.result.model.parameters()
                unresolved = {f'{p}{i}' for i, r in enumerate(w.result.resolved, start=1)
                              if not r for p in ('k', 'omega_', 'zeta_')}
                cells = ' '.join(f'{"(" + format(values.get(n, math.nan), ".5g") + ")":>13}'
                                 if n in unresolved else f'{values.get(n, math.nan):13.6g}'
                                 for n in names)
                lines.append(f'{w.window_index:>4} {w.target_angle:+8.3f} {cells}')
            lines.append('')
    if found.mismatched:
        lines.append(f'{len(found.mismatched)} window(s) do not match the model '
                     f'{found.model_name} (not identified):')
        for m in found.mismatched[:10]:
            lines.append(f'  window {m.window_index} ({m.target_angle:+g} deg, {m.moves} '
                         f'moves): {m.reason}')
        if len(found.mismatched) > 10:
            lines.append(f'  ... and {len(found.mismatched) - 10} more (see --json)')
        lines.append('')
    if found.pooled is not None:
        pooled = found.pooled
        values = pooled.model.parameters()
        stds = pooled.std_by_name()
        how = 'one joint fit' if found.pooling == 'joint' else 'inverse-variance combination'
        lines.append(f'pooled over {found.pooled_windows} window(s), {pooled.moves} moves '
                     f'({how}):')
        if found.pooling_note:
            lines.append(f'  note: {found.pooling_note}')
        for n in names:
            lines.append(f'  {n:<8} {values.get(n, math.nan):12.6g} +- '
                         f'{stds.get(n, math.nan):<10.3g} {parameter_unit(n):<12} '
                         f'({dev(values, n):+.3f} % vs reference {ref[n]:.6g})')
        lines.append(f'  input delay {pooled.input_delay * 1e6:.2f} us, '
                     f'amplifier lag {pooled.lag_time_constant * 1e6:.2f} us')
        lines.append('')
    lines.append(f'rejected: {len(found.rejected)} move(s) or message(s) set aside')
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in found.rejected:
        groups.setdefault(r['reason'], []).append(r)
    for reason, items in list(groups.items())[:20]:
        ids = [str(r['move_id']) for r in items if r['move_id'] is not None]
        where = f'moves {", ".join(ids[:5])}' + (f', ... {ids[-1]}' if len(ids) > 5 else '') \
            if len(ids) > 1 else f'move {ids[0]}' if ids else items[0].get('topic', 'message')
        lines.append(f'  {len(items)} x {reason} ({where})')
    if len(groups) > 20:
        lines.append(f'  ... and {len(groups) - 20} more reasons (see --json)')
    return '\n'.join(lines) + '\n'
