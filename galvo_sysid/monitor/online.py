"""Online identification without ROS: the names this module held before the split (issue 11).

Kept so that imports of before still work; new code imports from where the names live:

- :mod:`galvo_sysid.monitor.scheduler`: :class:`FitOutcome`, :func:`fit_window` and the
  window scheduler (``WindowFitter`` is its old name, :class:`WindowScheduler`);
- :mod:`galvo_sysid.monitor.ratelog`: :class:`RateLimitedLog`;
- :mod:`galvo_sysid.monitor.tasks`: :class:`SysidTask`, :class:`WatchdogTask`,
  :func:`mismatch_message`.
"""

from __future__ import annotations

from galvo_sysid.monitor.ratelog import RateLimitedLog
from galvo_sysid.monitor.scheduler import FitOutcome, WindowScheduler, fit_window
from galvo_sysid.monitor.tasks import SysidTask, WatchdogTask, mismatch_message

__all__ = [
    'FitOutcome',
    'RateLimitedLog',
    'SysidTask',
    'WatchdogTask',
    'WindowFitter',
    'WindowScheduler',
    'fit_window',
    'mismatch_message',
]

WindowFitter = WindowScheduler
"""The old name of :class:`~galvo_sysid.monitor.scheduler.WindowScheduler`."""
