"""``galvo-sysid``: the command-line tool for recorded data and field work.

Subcommands (``galvo-sysid <command> --help`` explains each):

- offline, no ROS graph needed: ``simulate`` (write a bag from the simulated scanner),
  ``identify`` (identify the plant from a bag), ``info`` (what a bag holds);
- live, on the ROS 2 graph: ``record``, ``replay``, ``echo`` (stand-ins for ``ros2 bag record``,
  ``ros2 bag play`` and ``ros2 topic echo`` where ros2cli is not installed).

Other modules add subcommands by being listed in :data:`PLUGINS` and defining
``register(subparsers)`` (see :func:`build_parser`).

Exit codes: 0 success, 1 bad input or nothing identified (one line on stderr, no traceback),
2 wrong usage, 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import math
import sys
import time
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    from collections.abc import Sequence

    from galvo_sysid.field.offline import BagIdentification

__all__ = ['COMMANDS', 'PLUGINS', 'build_parser', 'main', 'parse_angle']

PROG = 'galvo-sysid'

PLUGINS = ('galvo_sysid.cli.commission', 'galvo_sysid.cli.discrepancy')
"""Modules that add subcommands if present: each defines ``register(subparsers)``, which adds
its parser(s) and sets ``func`` (``args -> exit code``) as the parser default. ``register``
runs for every command except the built-in ones of :data:`COMMANDS` (so also for ``--help``
and the plugins' own commands); it should import nothing heavy: the numerics belong in
``func``. Errors derived from ``GalvoSysidError`` raised by ``func`` become one line on
stderr and exit code 1."""

COMMANDS = ('simulate', 'identify', 'info', 'record', 'replay', 'echo')
"""The built-in subcommands: running one of them registers no plugin (process start counts,
e.g. in identify's speed against real time)."""

_PSI = 0.3

_MAIN_HELP = """\
Field tools for galvano-scanner system identification (galvo_sysid).

The scanner's plant (a rigid-body mode plus three resonant modes) is identified from the
current and encoder records of ordinary positioning moves: topics /galvo/current and
/galvo/encoder (galvo_sysid_msgs/msg/MoveSamples, one message per move and signal).
Moves are grouped by target angle; every 100 moves of one angle form a window, which is
averaged and fitted (paper: Method A + ARX, or the refined fit), then judged for drift
against the reference model: a plant-model file (--model), by default the packaged model
of the paper's scanner (Table I). Data of another scanner are said to be so, not drift.
"""

_MAIN_EPILOG = """\
a first session (no ROS graph needed):
  galvo-sysid simulate --out /tmp/run1 --angles 1psi 2psi --moves-per-angle 200
  galvo-sysid info /tmp/run1
  galvo-sysid identify /tmp/run1
  galvo-sysid identify /tmp/run1 --json > run1.json
  galvo-sysid identify bags/drifting --plot drift.png

your own scanner (commission once, then monitor):
  galvo-sysid commission healthy.mcap --out scanner.yaml --plot scanner_bode.png
  galvo-sysid identify later.mcap --model scanner.yaml

on a running system (galvo_driver, sysid, watchdog nodes):
  galvo-sysid record --out /tmp/field1 --duration 30
  galvo-sysid echo /galvo/modal_parameters --once
  galvo-sysid replay /tmp/field1 --rate 2

exit codes: 0 ok, 1 bad input or nothing identified, 2 usage error, 130 interrupted
"""


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Keep the hand-made line breaks of descriptions; show defaults that say something."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ''
        default = action.default
        if (default is None or default is False or default == [] or default is argparse.SUPPRESS
                or '%(default)' in text or not action.option_strings):
            return text
        return f'{text} (default: %(default)s)'


def parse_angle(text: str) -> float:
    """Parse a target angle in degrees; ``'2psi'`` or ``'0.5psi'`` means multiples of 0.3 deg.

    Raises:
        argparse.ArgumentTypeError: Not a finite number.
    """
    raw = text.strip().lower()
    scale = 1.0
    if raw.endswith('psi'):
        raw, scale = raw[:-3] or '1', _PSI
    try:
        value = float(raw) * scale
    except ValueError:
        msg = f'not an angle: {text!r} (degrees, or e.g. 2psi = 0.6 deg)'
        raise argparse.ArgumentTypeError(msg) from None
    if not math.isfinite(value) or value == 0:
        msg = f'angle must be finite and non-zero: {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return round(value, 12)


def _nonnegative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        msg = f'not a whole number: {text!r}'
        raise argparse.ArgumentTypeError(msg) from None
    if value < 0:
        msg = f'must be >= 0: {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return value


def _positive(kind: type[int] | type[float]) -> Any:
    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            msg = f'not a number: {text!r}'
            raise argparse.ArgumentTypeError(msg) from None
        if not value > 0:
            msg = f'must be > 0: {text!r}'
            raise argparse.ArgumentTypeError(msg)
        return value
    parse.__name__ = kind.__name__
    return parse


# --------------------------------------------------------------------------- parser


def build_parser(*, plugins: bool = True) -> argparse.ArgumentParser:
    """The argument parser with every subcommand (and, if ``plugins``, those of
    :data:`PLUGINS` found installed)."""  # noqa: D205, D209
    parser = argparse.ArgumentParser(prog=PROG, description=_MAIN_HELP, epilog=_MAIN_EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    from galvo_sysid import __version__

    parser.add_argument('--version', action='version', version=f'%(prog)s {__version__}')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    _add_simulate(sub)
    _add_identify(sub)
    _add_info(sub)
    _add_record(sub)
    _add_replay(sub)
    _add_echo(sub)
    for name in PLUGINS if plugins else ():
        if importlib.util.find_spec(name) is not None:
            importlib.import_module(name).register(sub)
    return parser


def _add_simulate(sub: Any) -> None:
    p = sub.add_parser(
        'simulate', formatter_class=_Formatter,
        help='write a bag from the simulated scanner (fast, no ROS)',
        description=(
            "Run the closed-loop simulator (the plant of a model file, by default the paper's\n"
            'scanner of Table I; DSP delay + amplifier lag, quantised encoder, coloured\n'
            'noise, a positioning controller designed from the model) and write its moves\n'
            'into a rosbag2 bag: topics /galvo/current and /galvo/encoder (MoveSamples), the\n'
            'same messages the galvo_driver node publishes, with header stamps and log times\n'
            'in simulated time (starting at 0). No ROS graph is used: it runs as fast as the\n'
            'simulator. For each angle the scanner moves forward (+angle) and back (-angle)\n'
            'in turn, so --moves-per-angle 200 gives 100 moves of each sign: one window each.'),
        epilog=(
            'examples:\n'
            '  galvo-sysid simulate --out /tmp/nominal --angles 1psi --moves-per-angle 200\n'
            '  galvo-sysid simulate --out /tmp/paper --angles paper --moves-per-angle 200\n'
            '  galvo-sysid simulate --out /tmp/drift --angles 1psi --moves-per-angle 1000 \\\n'
            '      --drift omega_1=-2e-5/move\n'
            '  galvo-sysid simulate --out /tmp/step --angles 1psi 3psi --moves-per-angle 400 \\\n'
            '      --step k0=0.97@400 --effect coulomb_friction:friction_current=0.01\n'
            '  galvo-sysid simulate --out /tmp/long --angles 1psi --record-length 1024 \\\n'
            '      --model galvo_sysid/model/data/paper_table1.yaml   # from a source checkout'))
    p.add_argument('--out', required=True, metavar='BAG', help='bag directory to create')
    p.add_argument('--angles', nargs='+', default=['1psi'], metavar='ANGLE',
                   help="target angles [deg]; '2psi' = 2 x 0.3 deg; 'paper' = the paper's 19")
    p.add_argument('--moves-per-angle', type=_positive(int), default=200, metavar='N',
                   help='moves per angle (forward and back alternate)')
    p.add_argument('--seed', type=int, default=0, help='noise seed (same seed, same bag)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='rosbag2 storage format')
    p.add_argument('--model', metavar='FILE', default=None,
                   help="plant-model file of the scanner (default: the packaged model of the "
                        "paper's scanner); sets the sample period, record and dwell lengths")
    p.add_argument('--record-length', type=_positive(int), default=None, metavar='N',
                   help="recorded samples per move (default: the model's)")
    p.add_argument('--dwell-length', type=_nonnegative_int, default=None, metavar='N',
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
    p.set_defaults(func=_cmd_simulate)


def _add_identify(sub: Any) -> None:
    p = sub.add_parser(
        'identify', formatter_class=_Formatter,
        help='identify the plant from a bag, offline (no ROS)',
        description=(
            'Identify the scanner from a bag with the same code as the sysid node (so the\n'
            'numbers are the same): current and encoder messages are paired by move_id,\n'
            'grouped by signed target angle into windows of --window-size moves, each window\n'
            'is fitted (--method) and judged for drift like the watchdog node does. At the\n'
            'end of the bag, an unfinished window holding at least half a window is fitted\n'
            'too and marked partial. Moves that cannot be used (NaN, unpaired, duplicate\n'
            'move_id, wrong length, zero angle, ...) are listed as rejected with the reason;\n'
            'the rest is used.\n\n'
            "The scanner is the plant-model file of --model (default: the paper's scanner):\n"
            'its modes, bands, input dynamics and sample period are what is identified, and\n'
            'deviations are shown from it. Data that do not match it (another sample period,\n'
            'a mode outside its band, a residual far above the noise) are said so in one\n'
            'line: the scanner is another one (galvo-sysid commission makes its model).\n\n'
            'methods: refined  structured output-error fit of the modal model (default)\n'
            '         paper-A  the paper: average the moves, fictitious input, ARX(15,15)\n'
            '         paper-B  the paper: concatenate the moves instead of averaging'),
        epilog=(
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
            '      --watchdog-params config/watchdog.yaml   # as the deployed nodes are set'))
    p.add_argument('bag', help='rosbag2 bag: directory, .mcap or .db3 file')
    p.add_argument('--json', action='store_true', help='print one JSON object on stdout')
    p.add_argument('--method', choices=('refined', 'paper-A', 'paper-B'), default=None,
                   help="identification method (default: the sysid node's, refined)")
    p.add_argument('--plot', metavar='FILE',
                   help='also write Bode (identified vs reference) and parameter-trend plots '
                        '(.png, .pdf or .svg)')
    p.add_argument('--window-size', type=_positive(int), default=None, metavar='N',
                   help='moves per window (default: the sysid node parameter window_size, '
                        '100)')
    p.add_argument('--min-partial', type=_positive(int), default=None, metavar='N',
                   help='smallest unfinished window fitted at the end (default: half a window)')
    p.add_argument('--namespace', metavar='NS',
                   help='scanner namespace when the bag holds several (e.g. /left)')
    p.add_argument('--na', type=_positive(int), default=None, metavar='N',
                   help='ARX order of A[q] (paper pipeline; start of the refined fit); default: '
                        'the sysid node parameter na, 15')
    p.add_argument('--nb', type=_positive(int), default=None, metavar='N',
                   help='ARX order of B[q]; default: the sysid node parameter nb, 15')
    p.add_argument('--model', metavar='FILE', default=None,
                   help="plant-model file of the scanner (default: the sysid parameter model, "
                        "else the packaged model of the paper's scanner)")
    p.add_argument('--sysid-params', metavar='YAML',
                   help="the sysid node's --params-file (e.g. config/sysid.yaml): model, "
                        'window and pairing settings, method, na, nb; options given here win')
    p.add_argument('--watchdog-params', metavar='YAML',
                   help="the watchdog node's --params-file (e.g. config/watchdog.yaml): "
                        'reference model (its model; "" = the packaged paper model, as the '
                        'node) and tolerances of the drift verdicts (default: the reference '
                        'is the --model)')
    p.add_argument('--jobs', type=_positive(int), default=None, metavar='N',
                   help='windows fitted in parallel (default: one per CPU); the numbers do '
                        'not depend on it')
    p.add_argument('--pooling', choices=('joint', 'inverse-variance'), default=None,
                   help='pooled estimate: one joint fit to all windows (default for refined; '
                        'sharpest) or the inverse-variance combination of the windows '
                        '(default and only choice for the paper methods)')
    p.set_defaults(func=_cmd_identify)


def _add_info(sub: Any) -> None:
    p = sub.add_parser('info', formatter_class=_Formatter, help='show what a bag holds',
                       description='Topics, types, message counts and time range of a bag '
                                   '(like ros2 bag info).')
    p.add_argument('bag', help='rosbag2 bag: directory, .mcap or .db3 file')
    p.set_defaults(func=_cmd_info)


def _add_record(sub: Any) -> None:
    p = sub.add_parser(
        'record', formatter_class=_Formatter,
        help='record galvo topics of the live ROS graph into a bag',
        description=(
            'Record topics of the running system into a new rosbag2 bag, like\n'
            "'ros2 bag record': raw subscriptions (the bytes exactly as published), message\n"
            'type and QoS taken from the publishers, the message definitions stored in the\n'
            'bag so any rosbag2 reader decodes it. Topics are picked up when they appear.\n'
            'Log time = receive time. Stops after --duration or on Ctrl-C (the bag is closed\n'
            'properly either way).'),
        epilog=('examples:\n'
                '  galvo-sysid record --out /tmp/field1 --duration 60\n'
                '  galvo-sysid record --out /tmp/left --storage sqlite3 /left/galvo/current '
                '/left/galvo/encoder\n'
                '  galvo-sysid record --out /tmp/everything --all'))
    p.add_argument('--out', required=True, metavar='BAG', help='bag directory to create')
    p.add_argument('--duration', type=_positive(float), default=None, metavar='S',
                   help='stop after S seconds (default: until Ctrl-C)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='rosbag2 storage format')
    p.add_argument('-a', '--all', action='store_true',
                   help='record every topic (except /rosout and /parameter_events)')
    p.add_argument('topics', nargs='*', metavar='TOPIC',
                   help='topics to record (default: /galvo/current /galvo/encoder '
                        '/galvo/modal_parameters /galvo/drift)')
    p.set_defaults(func=_cmd_record)


def _add_replay(sub: Any) -> None:
    p = sub.add_parser(
        'replay', formatter_class=_Formatter, help='publish a bag onto the live ROS graph',
        description=(
            "Publish a bag's messages with their recorded timing, like 'ros2 bag play'.\n"
            'Waits (up to --wait seconds) until every topic has a subscriber, so nothing is\n'
            'lost at the start. --rate scales the timing; --clock publishes /clock with the\n'
            "bag's time for nodes run with use_sim_time:=true; --loop starts over at the end\n"
            '(the sysid node notices time jumping back and starts fresh windows).'),
        epilog=('examples:\n'
                '  galvo-sysid replay bags/nominal\n'
                '  galvo-sysid replay bags/drifting --rate 5 --loop\n'
                '  galvo-sysid replay run1 --clock --topics /galvo/current /galvo/encoder'))
    p.add_argument('bag', help='rosbag2 bag: directory, .mcap or .db3 file')
    p.add_argument('--rate', type=_positive(float), default=1.0, metavar='R',
                   help="speed factor (2 = twice as fast; 'inf' = as fast as possible)")
    p.add_argument('--loop', action='store_true', help='start over at the end')
    p.add_argument('--clock', action='store_true', help="publish /clock with the bag's time")
    p.add_argument('--topics', nargs='+', metavar='TOPIC', help='only these topics')
    p.add_argument('--wait', type=float, default=10.0, metavar='S',
                   help='wait at most S seconds for subscribers')
    p.set_defaults(func=_cmd_replay)


def _add_echo(sub: Any) -> None:
    p = sub.add_parser(
        'echo', formatter_class=_Formatter, help='print the messages of a live topic',
        description=(
            "Print a live topic's messages as YAML, like 'ros2 topic echo': the type is\n"
            'found from the graph (waits until the topic appears), the QoS follows the\n'
            'publishers, so /galvo/modal_parameters (transient local) shows the latest\n'
            'window at once.'),
        epilog=('examples:\n'
                '  galvo-sysid echo /galvo/modal_parameters --once\n'
                '  galvo-sysid echo /galvo/drift --json\n'
                '  galvo-sysid echo /diagnostics --timeout 5'))
    p.add_argument('topic', help='topic name')
    p.add_argument('--once', action='store_true', help='exit after the first message')
    p.add_argument('--json', action='store_true', help='one JSON object per line')
    p.add_argument('--timeout', type=_positive(float), default=None, metavar='S',
                   help='exit with code 1 when no message came within S seconds')
    p.set_defaults(func=_cmd_echo)


# --------------------------------------------------------------------------- progress


class _Progress:
    """A one-line progress bar on a TTY, drawn only when a run takes a while."""

    def __init__(self, stream: TextIO, label: str, *, enabled: bool,
                 delay: float = 0.5) -> None:
        self.stream = stream
        self.label = label
        self.enabled = enabled and stream.isatty()
        self.delay = delay
        self.start = time.monotonic()
        self.last = 0.0
        self.drawn = False

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self.start < self.delay or (now - self.last < 0.1 and done < total):
            return
        self.last = now
        frac = done / total if total else 1.0
        width = 30
        bar = '#' * round(frac * width)
        self.stream.write(f'\r{self.label} [{bar:<{width}}] {100 * frac:3.0f} % '
                          f'({done}/{total} messages, {now - self.start:.1f} s)')
        self.stream.flush()
        self.drawn = True

    def close(self) -> None:
        if self.drawn:
            self.stream.write('\r\033[K')
            self.stream.flush()


# --------------------------------------------------------------------------- commands


def _cmd_simulate(args: argparse.Namespace) -> int:
    from galvo_sysid.field.simulate import simulate_bag
    from galvo_sysid.model import load_model
    from galvo_sysid.sim.simulator import SimulatorConfig

    config = SimulatorConfig(plant=load_model(args.model or None),
                             record_length=args.record_length, dwell_length=args.dwell_length)
    summary = simulate_bag(args.out, angles=_angles(args.angles),
                           moves_per_angle=args.moves_per_angle, seed=args.seed,
                           storage=args.storage, drift=args.drift, steps=args.step,
                           effects=args.effect, config=config, model_path=args.model or '')
    print(summary, file=sys.stderr)
    return 0


def _angles(items: Sequence[str]) -> list[float]:
    from galvo_sysid.model import PAPER_ANGLES

    angles: list[float] = []
    for item in items:
        if item.lower() == 'paper':
            angles.extend(PAPER_ANGLES)
        else:
            try:
                angles.append(parse_angle(item))
            except argparse.ArgumentTypeError as err:
                from galvo_sysid.errors import ConfigurationError

                raise ConfigurationError(str(err)) from None
    return angles


def _cmd_identify(args: argparse.Namespace) -> int:
    from galvo_sysid.field.offline import (
        identify_bag,
        load_node_parameters,
        monitor_from_parameters,
    )

    if args.plot:  # say a bad file name before the work, not after
        from galvo_sysid.field.plots import check_plot_path

        check_plot_path(args.plot)
    from galvo_sysid.model import load_model
    from galvo_sysid.monitor.online import mismatch_message

    sysid: dict[str, Any] = {'window_size': 100, 'method': 'refined', 'na': 15, 'nb': 15,
                             'model': ''}
    if args.sysid_params:
        sysid.update(load_node_parameters(args.sysid_params, 'sysid'))
    for name in ('window_size', 'method', 'na', 'nb', 'model'):
        if getattr(args, name) is not None:
            sysid[name] = getattr(args, name)
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
    progress = _Progress(sys.stderr, 'identify', enabled=not args.json)
    try:
        found = identify_bag(args.bag, method=str(sysid['method']),
                             window_size=int(sysid['window_size']),
                             min_partial=args.min_partial, namespace=args.namespace,
                             monitor=monitor, na=int(sysid['na']), nb=int(sysid['nb']),
                             windower=sysid, jobs=args.jobs or _cpus(),
                             pooling=args.pooling, model=model, model_path=model_path,
                             progress=progress)
    finally:
        progress.close()
    if args.json:
        json.dump(_json_safe(found.to_dict()), sys.stdout, allow_nan=False)
        sys.stdout.write('\n')
    else:
        sys.stdout.write(format_identification(found))
    if args.plot:
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


def _cpus() -> int:
    import os

    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _json_safe(value: Any) -> Any:
    """Replace NaN/Inf by None so the output is strict JSON."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


def format_identification(found: BagIdentification) -> str:
    """The readable report ``identify`` prints without ``--json``."""
    from galvo_sysid.model import REFERENCE_MODEL, model_label

    reference = found.reference if found.reference is not None else REFERENCE_MODEL
    ref = reference.parameters()
    ref_name = found.reference_name or model_label(None)
    names = list(ref)
    info = found.info
    span = (info.end - info.start) * 1e-9
    lines = [f'bag: {info.path} ({info.storage}), {found.moves:g} moves, {span:.2f} s; '
             f'method {found.method}, windows of {found.window_size} moves; model '
             f'{found.model_name}',
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
                         f'{stds.get(n, math.nan):<10.3g} ({dev(values, n):+.3f} % vs '
                         f'reference {ref[n]:.6g})')
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


def _cmd_info(args: argparse.Namespace) -> int:
    from galvo_sysid.field.bags import BagReader

    with BagReader(args.bag) as bag:
        info = bag.info
    span = (info.end - info.start) * 1e-9
    print(f'bag:      {info.path}')
    print(f'storage:  {info.storage}')
    print(f'messages: {info.message_count}')
    print(f'time:     {info.start * 1e-9:.6f} s .. {info.end * 1e-9:.6f} s ({span:.3f} s)')
    print('topics:')
    width = max((len(t.topic) for t in info.topics), default=0)
    for t in info.topics:
        latched = ', transient local' if t.transient_local else ''
        print(f'  {t.topic:<{width}}  {t.msgtype}  ({t.count} messages{latched})')
    return 0


def _cmd_record(args: argparse.Namespace) -> int:
    from galvo_sysid.field.bags import GALVO_TOPICS
    from galvo_sysid.field.live import record

    topics = args.topics or ([] if args.all else list(GALVO_TOPICS))
    summary = record(args.out, topics=topics, all_topics=args.all, duration=args.duration,
                     storage=args.storage)
    total = sum(summary.counts.values())
    print(f'record: {total} messages on {len(summary.counts)} topic(s) in '
          f'{summary.seconds:.1f} s -> {args.out} ({args.storage})', file=sys.stderr)
    for topic, count in sorted(summary.counts.items()):
        print(f'  {topic}: {count}', file=sys.stderr)
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from galvo_sysid.field.live import replay

    replay(args.bag, rate=args.rate, loop=args.loop, clock=args.clock, topics=args.topics,
           wait=args.wait)
    return 0


def _cmd_echo(args: argparse.Namespace) -> int:
    from galvo_sysid.field.live import echo

    return echo(args.topic, once=args.once, as_json=args.json, timeout=args.timeout)


# --------------------------------------------------------------------------- main


def _one_line(err: BaseException) -> str:
    return ' '.join(str(err).split()) or type(err).__name__


_BLAS_THREADS = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``galvo-sysid``; return the exit code (see the module docs)."""
    import os

    # The fits solve many small problems: threaded BLAS only adds overhead there (measured:
    # 2.5x slower with two threads), and parallel windows use processes (--jobs) instead.
    # Set before numpy is imported; an explicit setting in the environment wins.
    for name in _BLAS_THREADS:
        os.environ.setdefault(name, '1')
    words = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(plugins=not words or words[0] not in COMMANDS)
    args = parser.parse_args(words)
    from galvo_sysid.errors import GalvoSysidError

    where = f'{PROG} {args.command}'
    try:
        return int(args.func(args))
    except GalvoSysidError as err:
        print(f'{where}: error: {_one_line(err)}', file=sys.stderr)
        return 1
    except OSError as err:  # unwritable output, full disk, ...
        print(f'{where}: error: {_one_line(err)}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f'{where}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':  # pragma: no cover
    sys.exit(main())
