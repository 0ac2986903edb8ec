"""The node parameters, one source: names, defaults, descriptions, ranges (no ROS).

One tuple of :class:`ParamSpec` per node: :data:`DRIVER_PARAMETERS` (``galvo_driver``),
:data:`SYSID_PARAMETERS` (``sysid``) and :data:`WATCHDOG_PARAMETERS` (``watchdog``), by node
name in :data:`NODE_PARAMETERS`. Everything else reads them:

- the nodes declare exactly these (:mod:`galvo_sysid.nodes.framework` builds the ROS
  descriptors and checks changes with :meth:`ParamSpec.check`);
- :class:`~galvo_sysid.monitor.pairing.MoveWindower` and
  :class:`~galvo_sysid.monitor.drift.DriftMonitor` take the defaults of the settings that are
  node parameters (:data:`WINDOWER_PARAMETERS`, :data:`MONITOR_PARAMETERS`) from here;
- ``galvo-sysid identify`` starts from :func:`defaults` of the sysid node;
- a test checks that ``config/*.yaml`` declare only these, with these defaults.
"""

from __future__ import annotations

import array
import math
import unicodedata
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.ident.methods import METHODS
from galvo_sysid.model import PAPER_ANGLES
from galvo_sysid.monitor.tolerances import KINDS, builtin_tolerance, parameter_kind

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

__all__ = [
    'CURRENTS',
    'DECLARED_MODES',
    'DRIVER_PARAMETERS',
    'MAX_ANGLES',
    'MAX_EFFECTS_TEXT',
    'MAX_LIST',
    'MAX_TEXT',
    'MONITOR_PARAMETERS',
    'NODE_PARAMETERS',
    'RELIABILITY',
    'SYSID_PARAMETERS',
    'WATCHDOG_PARAMETERS',
    'WINDOWER_PARAMETERS',
    'ParamSpec',
    'defaults',
    'tolerance_specs',
]

RELIABILITY = ('reliable', 'best_effort')
"""Choices of the move topics' reliability (``qos_reliability`` parameters)."""

CURRENTS = ('command', 'measured')
"""What the current topic may carry (the sysid parameter ``current``)."""


MAX_TEXT = 4096
"""Longest text parameter [characters] unless its spec says otherwise (a path fits)."""

MAX_LIST = 1000
"""Most elements of a list parameter unless its spec says otherwise."""

MAX_ANGLES = 256
"""Most angles in the driver's schedule (the paper's has 19)."""

MAX_EFFECTS_TEXT = 65_536
"""Longest ``effects`` JSON [characters] (checked before it is parsed)."""


def _show(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to about ``limit`` characters (a value quoted in a reason)."""
    if isinstance(value, list | tuple) and len(value) > limit:  # never repr a huge list
        value = [*value[:limit], ...]
    text = repr(value)
    return text if len(text) <= limit else f'{text[:limit - 3]}...'


def _kind(value: Any) -> str:
    names = {bool: 'a boolean', int: 'an integer', float: 'a floating-point number',
             str: 'text', list: 'a list', tuple: 'a list', type(None): 'no value'}
    return names.get(type(value), type(value).__name__)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


@dataclass(frozen=True)
class ParamSpec:
    """One declared parameter: default, description and (for numbers) an inclusive range.

    A ``low``/``high`` of None leaves that side open (the check is done in Python; ROS
    ranges need both ends, so a half-open range is declared without a ROS range). A default
    of None declares an optional number: not set unless given (a parameter file, the
    command line, a live change), its value None until then; ``builtin`` is then the value
    that applies while it is not set (what a parameter file may spell out).

    The value's type is the default's, as ROS takes it: an integer parameter refuses 10.7
    (and 10.0), a floating-point one refuses an integer (ROS does: write ``2.0``), a list
    holds numbers of the default's element type, each checked against the range (and each
    finite). Texts and
    lists have bounded lengths; texts refuse control characters (one line each, except a
    ``multiline`` text: tabs and line breaks allowed).

    Attributes:
        name: The parameter's name (``tolerances.k0``: nested ``tolerances: {k0: ...}`` in
            a parameter file).
        default: Its default value (its type is the parameter's type).
        description: What it is, one line.
        low: Smallest value of a number (or of each number of a list), None: open.
        high: Largest value, None: open.
        read_only: Read at start-up only.
        choices: The values a string may take (empty: any).
        exclusive_low: ``low`` itself is not allowed.
        builtin: For an optional number (default None): the value that applies while it is
            not set.
        zero_off: 0 is allowed too, below ``low``: it switches the setting off (e.g. a
            period of 0: never); other values below ``low`` are refused.
        min_length: Fewest elements of a list.
        max_length: Most elements of a list or characters of a text (None:
            :data:`MAX_LIST` / :data:`MAX_TEXT`).
        multiline: A text that may hold tabs and line breaks (JSON).
    """

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    read_only: bool = False
    choices: tuple[str, ...] = ()
    exclusive_low: bool = False
    builtin: float | None = None
    zero_off: bool = False
    min_length: int = 0
    max_length: int | None = None
    multiline: bool = False

    @property
    def text(self) -> str:
        """The description with the choices, as the node declares it."""
        if self.choices:
            return f'{self.description} (one of: {", ".join(self.choices)})'
        return self.description

    def check(self, value: Any) -> str | None:
        """Why ``value`` is not acceptable (one short line), or None.

        A list may come as a list, a tuple or an ``array.array`` (rclpy gives arrays set at
        run time as ``array.array``).
        """
        if isinstance(value, array.array):
            value = value.tolist()
        why = self._type_error(value)
        if why is not None:
            return why
        if isinstance(value, str):
            return self._text_error(value)
        if isinstance(value, list | tuple):
            if len(value) < self.min_length:
                return (f'{self.name} must not be empty' if self.min_length == 1 else
                        f'{self.name} must have at least {self.min_length} elements')
            most = MAX_LIST if self.max_length is None else self.max_length
            if len(value) > most:
                return f'{self.name} must have at most {most} elements, got {len(value)}'
            values: Sequence[Any] = value
        else:
            values = [value]
        for v in values:
            if _is_number(v):
                why = self._number_error(v)
                if why is not None:
                    return why
        return None

    def _type_error(self, value: Any) -> str | None:
        """Why ``value`` is not of this parameter's type (ROS's, from the default), or None."""
        default = self.default
        if default is None:  # an optional number: dynamically typed
            if value is None or _is_number(value):
                return None
            return f'{self.name} must be a number, got {_show(value)}'
        if isinstance(default, list | tuple):
            item = type(default[0]) if default else float
            if not isinstance(value, list | tuple):
                return f'{self.name} must be a list of numbers, got {_kind(value)}'
            for v in value:
                if type(v) is not item:
                    hint = ' (write 2.0 for 2)' if item is float and type(v) is int else ''
                    plural = {float: 'floating-point numbers', int: 'integers',
                              bool: 'booleans', str: 'texts'}.get(item, item.__name__)
                    return (f'{self.name} must be a list of {plural}{hint}, got '
                            f'{_kind(v)} {_show(v)}')
            return None
        if type(value) is type(default):
            return None
        need = _kind(default)
        if isinstance(default, float) and type(value) is int:
            need += f' (ROS refuses an integer here: write {value}.0)'
        if isinstance(default, int) and not isinstance(default, bool) and \
                isinstance(value, float) and math.isfinite(value):
            return f'{self.name} must be an integer, got {_show(value)}'
        return f'{self.name} must be {need}, got {_kind(value)} {_show(value)}'

    def _text_error(self, value: str) -> str | None:
        most = MAX_TEXT if self.max_length is None else self.max_length
        if len(value) > most:
            return f'{self.name} must be at most {most} characters, got {len(value)}'
        allowed = '\t\n\r' if self.multiline else ''
        bad = next((c for c in value if unicodedata.category(c) == 'Cc' and c not in allowed),
                   None)
        if bad is not None:
            return f'{self.name} must not hold control characters, got {bad!r}'
        if self.choices and value not in self.choices:
            return f'{self.name} must be one of {list(self.choices)}, got {_show(value)}'
        return None

    def _number_error(self, v: float) -> str | None:
        if isinstance(v, float) and not math.isfinite(v):
            return f'{self.name} must be finite, got {v}'
        if self.zero_off and v == 0:
            return None
        if self.low is not None and (v < self.low or (self.exclusive_low and v <= self.low)):
            op = '>' if self.exclusive_low else '>='
            off = ' (or 0: off)' if self.zero_off else ''
            return f'{self.name} must be {op} {self.low:g}{off}, got {_show(v)}'
        if self.high is not None and v > self.high:
            return f'{self.name} must be <= {self.high:g}, got {_show(v)}'
        return None


# -- galvo_driver ---------------------------------------------------------------------------
DRIVER_PARAMETERS = (
    ParamSpec('model', '', 'plant-model file of the simulated scanner ("": the packaged model of '
              "the paper's scanner)", read_only=True),
    ParamSpec('record_length', 0, "recorded samples per move (0: the model's)", 0, 1_000_000,
              read_only=True),
    ParamSpec('dwell_length', -1, 'samples between a record and the next move (-1: the '
              "model's)", -1, 1_000_000, read_only=True),
    ParamSpec('angles', list(PAPER_ANGLES), 'rotation angles of the schedule [deg] (positive; '
              'each is moved forward then back)', 1e-6, 20.0, min_length=1,
              max_length=MAX_ANGLES),
    ParamSpec('moves_per_angle', 200, 'moves per angle, alternating +a/-a (even)', 2, 1_000_000),
    ParamSpec('cycles', 0, 'times through the schedule (0: forever)', 0, 1_000_000_000),
    ParamSpec('rate_factor', 1.0, 'simulated seconds per wall second (1 real time, 0 as fast '
              'as possible)', 1e-3, 1e6, zero_off=True),
    ParamSpec('seed', 0, 'noise seed', 0, 2**31 - 1, read_only=True),
    ParamSpec('wait_for_subscribers', 1, 'subscribers each topic needs before moves start '
              '(0: start at once)', 0, 1000),
    ParamSpec('wait_timeout', 0.0, 'give up waiting for subscribers after this long and start '
              'anyway [s] (0: wait forever)', 0.0, 1e6),
    ParamSpec('exit_when_done', False, 'exit once the schedule is done (cycles > 0)'),
    ParamSpec('qos_depth', 1000, 'publisher queue depth (0: keep all)', 0, 1_000_000,
              read_only=True),
    ParamSpec('qos_reliability', 'reliable', 'publisher QoS reliability (best_effort reaches '
              'only best-effort subscribers)', choices=RELIABILITY, read_only=True),
    ParamSpec('drift.parameter', '', 'plant parameter that drifts ("" for none; k0, k<i>, '
              'omega_<i>, zeta_<i>, lag_time_constant, dead_time, friction_current, '
              'pivot_frequency, gain_ratio, current_limit, viscous_coefficient, '
              'cogging_amplitude, cogging_period, cogging_phase, encoder_error_amplitude, '
              'encoder_error_period, encoder_error_phase)'),
    ParamSpec('drift.rate', 0.0, 'relative change per drift.unit (e.g. -0.001)', -1.0, 1.0),
    ParamSpec('drift.unit', 'second', 'unit of the drift rate', choices=('second', 'move')),
    ParamSpec('step.parameter', '', 'plant parameter that steps ("" for none; names as '
              'drift.parameter)'),
    ParamSpec('step.factor', 1.0, 'the step multiplies the parameter by this', 0.01, 100.0),
    ParamSpec('step.at_move', -1, 'move index of the step (-1: the next move)', -1, 2**62),
    ParamSpec('effects', '[]', "physical effects added to the model's, as JSON: [{\"effect\": "
              'name, "parameters": {...}}, ...] (see galvo_sysid.model.effects)',
              max_length=MAX_EFFECTS_TEXT, multiline=True),
    ParamSpec('dither.amplitude', 0.0, "amplitude of each dither tone added to every move's "
              'current command [A] (0: none; galvo-sysid plan says what it buys and costs)',
              0.0, 0.5, read_only=True),
    ParamSpec('dither.modes', 'all', "the model's resonances the dither tones sit at: 'all' or "
              "mode numbers, comma-separated (e.g. '3')", max_length=64, read_only=True),
)
"""Parameters of the simulated scanner (``galvo_driver``)."""

# -- sysid ----------------------------------------------------------------------------------
_WINDOWER_SPECS = (
    ParamSpec('window_size', 100, 'moves of one signed target angle per identification window',
              2, 100_000),
    ParamSpec('samples', 0, 'expected samples per record (0: any; moves of each length '
              'fill windows of their own)', 0, 10_000_000),
    ParamSpec('max_samples', 65536, 'largest record accepted [samples]', 32, 10_000_000),
    ParamSpec('pair_timeout', 1.0, "a half is set aside as unpaired when its partner's topic "
              'is this far past it by stamps (or its own topic 11 times this far, where the '
              "partner's topic lags or has not come) [s]", 0.0, 3600.0, exclusive_low=True),
    ParamSpec('time_jump', 1.0, "a stamp this far from its topic's data clock is held apart: "
              'set aside alone, unless the next halves of that topic confirm the new time (a '
              'loop back then restarts the buffers) [s]', 0.0, 1e6, exclusive_low=True),
    ParamSpec('max_pending', 2000, 'most unpaired halves held', 1, 10_000_000),
    ParamSpec('max_windows', 64, 'most open windows held (one per target angle, sample period '
              'and record length)', 1, 100_000),
    ParamSpec('max_buffered_bytes', 268_435_456, 'most bytes of samples held (open windows, '
              'and a quarter of it at most for halves waiting)', 1_000_000, 1_000_000_000_000),
    ParamSpec('window_timeout', 300.0, 'a window not complete this long after its first move '
              '(by stamps) is set aside [s]', 0.0, 1e7, exclusive_low=True),
)

SYSID_PARAMETERS = (
    ParamSpec('model', '', 'plant-model file of the scanner ("": the packaged model of the '
              "paper's scanner); read at start-up", read_only=True),
    *_WINDOWER_SPECS,
    ParamSpec('current', 'command', "what the current topic carries: 'command' (the DSP's "
              "current command) or 'measured' (the coil current read when the encoder is: "
              'each window made into the held current that drives it, through '
              'measured_current_lag)', choices=CURRENTS, read_only=True),
    ParamSpec('measured_current_lag', 0.0, "the amplifier's lag time constant of a measured "
              'current [s] (galvo-sysid commission --measured-current finds it)', 0.0, 0.1,
              read_only=True),
    ParamSpec('method', 'refined', 'identification method', choices=METHODS),
    ParamSpec('na', 15, 'ARX order of A[q] (paper pipeline, also the refined start)', 2, 60),
    ParamSpec('nb', 15, 'ARX order of B[q] (paper pipeline, also the refined start)', 2, 60),
    ParamSpec('warm_start', True, "start each window's refined fit from the previous window "
              'of its angle, or of its sign where the angle has none yet, or from the model '
              'file where neither has (refitted afresh where that fit is not plausible)'),
    ParamSpec('fit_budget_ms', 0.0, "milliseconds from a window's completion past which its "
              "refined fit leaves out the weakly excited modes' band profiles (those modes "
              'reported unresolved, the window counted in windows_cut_short; 0: no budget)',
              1.0, 60_000.0, zero_off=True),
    ParamSpec('queue_size', 16, 'windows waiting for a fit at most (oldest dropped beyond)',
              1, 10_000, read_only=True),
    ParamSpec('fit_processes', 2, 'child processes for the fits (0: fit on a thread)', 0, 16,
              read_only=True),
    ParamSpec('qos_depth', 1000, 'input queue depth per topic (0: keep all)', 0, 1_000_000,
              read_only=True),
    ParamSpec('qos_reliability', 'reliable', 'input QoS reliability (best_effort for a lossy '
              'link: takes reliable and best-effort publishers, lost moves are not resent)',
              choices=RELIABILITY, read_only=True),
    ParamSpec('warnings_per_second', 20, 'most warning lines a second (the rest summed up)',
              1, 100, read_only=True),
    ParamSpec('stats_period', 30.0, 'log counters every this many seconds (0: never; else at '
              'least 0.1)', 0.1, 1e6, zero_off=True),
    ParamSpec('diagnostics_period', 1.0, 'publish counters on /diagnostics every this many '
              'seconds (0: never; else at least 0.1)', 0.1, 1e6, read_only=True,
              zero_off=True),
    ParamSpec('hardware_id', '', "the scanner's name in diagnostics (default: the namespace)"),
)
"""Parameters of online identification (``sysid``)."""

WINDOWER_PARAMETERS = tuple(s.name for s in _WINDOWER_SPECS)
"""Settings of :class:`~galvo_sysid.monitor.pairing.MoveWindower` that are sysid node
parameters of the same name (the one list used by the sysid node and by ``galvo-sysid
identify``)."""

# -- watchdog -------------------------------------------------------------------------------
DECLARED_MODES = 3
"""Modes whose tolerances the watchdog always declares (the paper's); a model with more modes
gets the rest declared at start-up (:func:`tolerance_specs`)."""


def _tolerance_spec(name: str) -> ParamSpec:
    """An optional tolerance parameter (not set: the rule of galvo_sysid.monitor.tolerances)."""
    builtin = builtin_tolerance(name)
    if name in KINDS:
        text = (f'relative tolerance of every {name} parameter without its own tolerance '
                f'(0.01 = 1 %; not set: the built-in defaults)')
    else:
        kind = parameter_kind(name)
        fallback = '' if kind == 'k0' else f'tolerances.{kind}, else '
        text = (f'relative tolerance of {name} (0.01 = 1 %; not set: {fallback}'
                f'{100 * builtin:g} %)')
    return ParamSpec(f'tolerances.{name}', None, text, 0.0, 1e6, exclusive_low=True,
                     builtin=builtin)


def tolerance_specs(n_modes: int, *, first_mode: int = 1) -> tuple[ParamSpec, ...]:
    """The tolerance parameters of modes ``first_mode`` .. ``n_modes`` (from mode 1: with
    ``tolerances.k0`` and the kinds first)."""  # noqa: D205, D209
    names = [f'{prefix}{i}' for prefix in ('k', 'omega_', 'zeta_')
             for i in range(max(1, first_mode), n_modes + 1)]
    head = ['k0', *KINDS] if first_mode <= 1 else []
    return tuple(_tolerance_spec(n) for n in (*head, *names))


_MONITOR_SPECS = (
    ParamSpec('warn_fraction', 0.5, 'a significant deviation past this fraction of its '
              'tolerance warns', 0.0, 1.0),
    ParamSpec('n_sigma', 3.0, 'deviations within this many standard deviations are noise',
              0.0, 100.0),
    ParamSpec('trend_windows', 8, 'windows in the drift trend test (0: off)', 0, 1000),
    ParamSpec('trend_min_windows', 3, 'fewest windows before the trend test speaks', 3, 1000),
    ParamSpec('trend_sigma', 4.0, 'trend slope significance needed [standard errors]',
              0.0, 100.0),
    ParamSpec('trend_fraction', 0.3, 'a trend is flagged once past this fraction of the '
              'tolerance', 0.0, 1.0),
    ParamSpec('step_fraction', 0.5, 'a jump between windows past this fraction of the '
              'tolerance restarts the trend history', 0.0, 1e6),
    ParamSpec('min_fit_percent', 75.0, 'windows fitting worse than this warn [%]', -1e9, 100.0),
)

WATCHDOG_PARAMETERS = (
    ParamSpec('model', '', 'plant-model file of the reference ("": the packaged model of the '
              "paper's scanner, Table I); read at start-up", read_only=True),
    *tolerance_specs(DECLARED_MODES),
    *_MONITOR_SPECS,
    ParamSpec('stale_timeout', 5.0, 'STALE after this long without a result [s]',
              0.0, 1e6, exclusive_low=True),
    ParamSpec('publish_rate', 1.0, 'diagnostics per second', 0.0, 10.0, exclusive_low=True,
              read_only=True),
    ParamSpec('hardware_id', '', "the scanner's name in diagnostics (default: the namespace)"),
)
"""Parameters of the drift watchdog (``watchdog``); the tolerances of modes beyond
:data:`DECLARED_MODES` are declared at start-up (:func:`tolerance_specs`)."""

MONITOR_PARAMETERS = tuple(s.name for s in _MONITOR_SPECS)
"""Options of :class:`~galvo_sysid.monitor.drift.DriftMonitor` that are watchdog node
parameters of the same name."""

NODE_PARAMETERS: Mapping[str, tuple[ParamSpec, ...]] = {
    'galvo_driver': DRIVER_PARAMETERS,
    'sysid': SYSID_PARAMETERS,
    'watchdog': WATCHDOG_PARAMETERS,
}
"""The parameters of each node, by node name."""


def defaults(node: str) -> dict[str, Any]:
    """The default parameter values of a node, by name (a new dictionary, lists copied).

    Args:
        node: ``'galvo_driver'``, ``'sysid'`` or ``'watchdog'``.

    Example: ``defaults('sysid')['window_size'] == 100``.

    Raises:
        ConfigurationError: Unknown node.
    """
    specs = NODE_PARAMETERS.get(node)
    if specs is None:
        raise ConfigurationError(f'unknown node {node!r}; known: {", ".join(NODE_PARAMETERS)}')
    return {s.name: list(s.default) if isinstance(s.default, list) else s.default
            for s in specs}
