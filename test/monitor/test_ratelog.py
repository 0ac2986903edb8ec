"""The rate-limited log (galvo_sysid.monitor.ratelog)."""

from __future__ import annotations

from galvo_sysid.monitor.ratelog import RateLimitedLog


def test_rate_limited_log_sums_up_a_flood() -> None:
    lines: list[str] = []
    now = [0.0]
    log = RateLimitedLog(lines.append, per_second=3, clock=lambda: now[0])
    for i in range(10):
        log(f'bad move {i}', key='bad move')
    assert lines == ['bad move 0', 'bad move 1', 'bad move 2']
    now[0] = 1.5
    log.flush()
    assert lines[-1] == '7 more similar message(s) held back in the last second: 7 x bad move'
    log('next')
    assert lines[-1] == 'next'
