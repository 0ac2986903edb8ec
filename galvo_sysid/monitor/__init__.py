"""Online monitoring without ROS: pairing, windows, fits, drift verdicts, the nodes' logic.

The modules, by noun:

- :mod:`~galvo_sysid.monitor.moves`: a half of a move (:class:`MoveHalf`) and a window of
  moves (:class:`Window`);
- :mod:`~galvo_sysid.monitor.pairing`: :class:`MoveWindower` pairs halves into moves and
  cuts windows per signed target angle;
- :mod:`~galvo_sysid.monitor.checks`, :mod:`~galvo_sysid.monitor.halves`,
  :mod:`~galvo_sysid.monitor.clock`, :mod:`~galvo_sysid.monitor.windows`: its parts (the
  checks, the halves waiting by move_id, the data clock, the open windows);
- :mod:`~galvo_sysid.monitor.rejections`: moves set aside (:class:`Rejection`) and the lines
  that say them;
- :mod:`~galvo_sysid.monitor.scheduler`: the one window scheduler
  (:class:`WindowScheduler`), fitting windows off the caller's thread in child processes,
  for the sysid node and ``galvo-sysid identify``;
- :mod:`~galvo_sysid.monitor.verdict`: verdict levels, result statuses,
  :class:`DriftVerdict`;
- :mod:`~galvo_sysid.monitor.tolerances`: parameter names, kinds, default tolerances and the
  rule that picks a tolerance;
- :mod:`~galvo_sysid.monitor.drift`: :class:`DriftMonitor`, one verdict per window;
- :mod:`~galvo_sysid.monitor.reference`: the watchdog's reference model and monitor from its
  parameters;
- :mod:`~galvo_sysid.monitor.ratelog`: :class:`RateLimitedLog`;
- :mod:`~galvo_sysid.monitor.tasks`: the task objects the nodes wire (:class:`SysidTask`,
  :class:`WatchdogTask`);
- :mod:`~galvo_sysid.monitor.parameters`: the node parameters (names, defaults, ranges), the
  one source for the nodes, the command line and ``config/*.yaml``.

The names below are loaded when first used, so that importing one module (say
:mod:`~galvo_sysid.monitor.moves`) does not import them all.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from galvo_sysid import lazy_names

if TYPE_CHECKING:
    from galvo_sysid.monitor.drift import DriftMonitor
    from galvo_sysid.monitor.moves import MoveHalf, Window
    from galvo_sysid.monitor.pairing import MoveWindower
    from galvo_sysid.monitor.parameters import ParamSpec, defaults
    from galvo_sysid.monitor.ratelog import RateLimitedLog
    from galvo_sysid.monitor.reference import monitor_from_parameters
    from galvo_sysid.monitor.rejections import Rejection, summarize_rejections
    from galvo_sysid.monitor.scheduler import FitOutcome, WindowScheduler, fit_window
    from galvo_sysid.monitor.tasks import SysidTask, WatchdogTask
    from galvo_sysid.monitor.verdict import DriftVerdict

__all__ = [
    'DriftMonitor',
    'DriftVerdict',
    'FitOutcome',
    'MoveHalf',
    'MoveWindower',
    'ParamSpec',
    'RateLimitedLog',
    'Rejection',
    'SysidTask',
    'WatchdogTask',
    'Window',
    'WindowScheduler',
    'defaults',
    'fit_window',
    'monitor_from_parameters',
    'summarize_rejections',
]

_WHERE = {
    'DriftMonitor': 'drift', 'DriftVerdict': 'verdict', 'FitOutcome': 'scheduler',
    'MoveHalf': 'moves', 'MoveWindower': 'pairing', 'ParamSpec': 'parameters',
    'RateLimitedLog': 'ratelog', 'Rejection': 'rejections', 'SysidTask': 'tasks',
    'WatchdogTask': 'tasks', 'Window': 'moves', 'WindowScheduler': 'scheduler',
    'defaults': 'parameters', 'fit_window': 'scheduler',
    'monitor_from_parameters': 'reference', 'summarize_rejections': 'rejections',
}


__getattr__ = lazy_names(__name__, _WHERE)
