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

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.ident.identify import METHODS
from galvo_sysid.model import PAPER_ANGLES
from galvo_sysid.monitor.tolerances import KINDS, builtin_tolerance, parameter_kind

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

__all__ = [
    'DECLARED_MODES',
    'DRIVER_PARAMETERS',
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


@dataclass(frozen=True)
class ParamSpec:
    """One declared parameter: default, description and (for numbers) an inclusive range.

    A ``low``/``high`` of None leaves that side open (the check is done in Python; ROS
    ranges need both ends, so a half-open range is declared without a ROS range). A default
    of None declares an optional number: not set unless given (a parameter file, the
    command line, a live change), its value None until then; ``builtin`` is then the value
    that applies while it is not set (what a parameter file may spell out).

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

    @property
    def text(self) -> str:
        """The description with the choices, as the node declares it."""
        if self.choices:
            return f'{self.description} (one of: {", ".join(self.choices)})'
        return self.description

    def check(self, value: Any) -> str | None:
        """Why ``value`` is not acceptable, or None."""
        if self.choices and value not in self.choices:
            return f'{self.name} must be one of {list(self.choices)}, got {value!r}'
        if self.default is None and value is not None and (
                isinstance(value, bool) or not isinstance(value, int | float)):
            return f'{self.name} must be a number, got {value!r}'
        values: Sequence[Any]
        values = value if isinstance(value, list | tuple) else [value]
        for v in values:
            if isinstance(v, bool) or not isinstance(v, int | float):
                continue
            if isinstance(v, float) and not math.isfinite(v):
                return f'{self.name} must be finite, got {v}'
            if self.low is not None and (v < self.low or (self.exclusive_low and v <= self.low)):
                op = '>' if self.exclusive_low else '>='
                return f'{self.name} must be {op} {self.low:g}, got {v}'
            if self.high is not None and v > self.high:
                return f'{self.name} must be <= {self.high:g}, got {v}'
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
              'each is moved forward then back)', 1e-6, 20.0),
    ParamSpec('moves_per_angle', 200, 'moves per angle, alternating +a/-a (even)', 2, 1_000_000),
    ParamSpec('cycles', 0, 'times through the schedule (0: forever)', 0, 1_000_000_000),
    ParamSpec('rate_factor', 1.0, 'simulated seconds per wall second (1 real time, 0 as fast '
              'as possible)', 0.0, 1e6),
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
              'pivot_frequency, gain_ratio, current_limit)'),
    ParamSpec('drift.rate', 0.0, 'relative change per drift.unit (e.g. -0.001)', -1.0, 1.0),
    ParamSpec('drift.unit', 'second', 'unit of the drift rate', choices=('second', 'move')),
    ParamSpec('step.parameter', '', 'plant parameter that steps ("" for none; names as '
              'drift.parameter)'),
    ParamSpec('step.factor', 1.0, 'the step multiplies the parameter by this', 0.01, 100.0),
    ParamSpec('step.at_move', -1, 'move index of the step (-1: the next move)', -1, 2**62),
    ParamSpec('effects', '[]', "physical effects added to the model's, as JSON: [{\"effect\": "
              'name, "parameters": {...}}, ...] (see galvo_sysid.model.effects)'),
)
"""Parameters of the simulated scanner (``galvo_driver``)."""

# -- sysid ----------------------------------------------------------------------------------
_WINDOWER_SPECS = (
    ParamSpec('window_size', 100, 'moves of one signed target angle per identification window',
              2, 100_000),
    ParamSpec('samples', 0, 'expected samples per record (0: the first move of a window '
              'fixes it)', 0, 10_000_000),
    ParamSpec('max_samples', 65536, 'largest record accepted [samples]', 32, 10_000_000),
    ParamSpec('pair_timeout', 1.0, 'a half still unpaired this long (by stamps) is set aside '
              '[s]', 0.0, 3600.0, exclusive_low=True),
    ParamSpec('time_jump', 1.0, 'stamps jumping back by more than this reset the buffers [s]',
              0.0, 1e6, exclusive_low=True),
    ParamSpec('max_pending', 2000, 'most unpaired halves held', 1, 10_000_000),
    ParamSpec('max_windows', 64, 'most open windows held (distinct target angles)', 1, 100_000),
    ParamSpec('max_buffered_samples', 20_000_000, 'most samples held in open windows',
              1000, 2_000_000_000),
)

SYSID_PARAMETERS = (
    ParamSpec('model', '', 'plant-model file of the scanner ("": the packaged model of the '
              "paper's scanner); read at start-up", read_only=True),
    *_WINDOWER_SPECS,
    ParamSpec('method', 'refined', 'identification method', choices=METHODS),
    ParamSpec('na', 15, 'ARX order of A[q] (paper pipeline, also the refined start)', 2, 60),
    ParamSpec('nb', 15, 'ARX order of B[q] (paper pipeline, also the refined start)', 2, 60),
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
              1, 10_000),
    ParamSpec('stats_period', 30.0, 'log counters every this many seconds (0: never)',
              0.0, 1e6),
    ParamSpec('diagnostics_period', 1.0, 'publish counters on /diagnostics every this many '
              'seconds (0: never)', 0.0, 1e6, read_only=True),
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
    ParamSpec('publish_rate', 1.0, 'diagnostics per second', 0.0, 1000.0, exclusive_low=True,
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
