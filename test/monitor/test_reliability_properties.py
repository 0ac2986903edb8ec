"""Reliability under bad input, shown with hypothesis (issue 7, "Bad input").

Pairing and buffering (galvo_sysid.monitor.pairing, galvo_sysid.interfaces.messages,
galvo_sysid.monitor.tasks):

- a stream of moves, each with at most one fault (NaN/Inf samples, empty or oversized record,
  lengths differing, zero angle, bad sample period, angles disagreeing, a missing partner, a
  half seen twice), arriving slightly out of order: every good move ends in exactly one
  window with its own samples, every faulty move is set aside exactly once and never enters a
  window, every repeat is said once; the same with tight memory limits (an evicted move is
  set aside once, never also windowed);
- a replay looping back in time (same move_ids again): no window mixes the two passes;
- arbitrary MoveSamples-like objects through the message conversion, the windower and the
  sysid task: a MoveHalf or InvalidDataError, never anything else.

Numerics entry points (identify_window, paper_pipeline, fit_arx, validate_records,
estimate_delay, pool_results, DriftMonitor.assess, result_from_msg): arbitrary arrays and
values, and simulated windows spoilt in arbitrary ways, give a result or a typed
GalvoSysidError, never another exception.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from galvo_sysid.errors import (
    ConfigurationError,
    GalvoSysidError,
    InvalidDataError,
    ModelMismatchError,
)
from galvo_sysid.ident.arx import fit_arx, min_data_length
from galvo_sysid.ident.delay import estimate_delay
from galvo_sysid.ident.identify import identify_window
from galvo_sysid.ident.paper import paper_pipeline
from galvo_sysid.ident.pool import pool_results
from galvo_sysid.ident.preprocess import MIN_ANGLE_SPAN, validate_records
from galvo_sysid.ident.result import IdentificationResult
from galvo_sysid.interfaces.messages import move_half_from_msg, result_from_msg
from galvo_sysid.model import REFERENCE_MODEL
from galvo_sysid.monitor.drift import DriftMonitor
from galvo_sysid.monitor.moves import MoveHalf, Window
from galvo_sysid.monitor.pairing import MoveWindower
from galvo_sysid.monitor.rejections import Rejection
from galvo_sysid.monitor.scheduler import FitOutcome
from galvo_sysid.monitor.tasks import SysidTask
from galvo_sysid.monitor.verdict import ERROR, MISMATCH, OK, WARN
from galvo_sysid.sim.simulator import simulate_window

N = 48
DT = 1e-5
MOVE_TIME = 0.006
FAULTS = ('nan_current', 'inf_encoder', 'nan_stamp', 'empty_current', 'oversized_encoder',
          'short_encoder', 'lengths_differ', 'zero_angle', 'zero_period', 'negative_period',
          'angles_disagree', 'missing_encoder', 'missing_current', 'bad_signal')
REPEATS = ('repeat_current', 'repeat_encoder')
KINDS = ('ok',) * 6 + FAULTS + REPEATS



def examples(n: int) -> settings:
    """Hypothesis settings: ``n`` examples, no deadline (fits vary in time on a busy CI)."""
    return settings(max_examples=n, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@dataclass(frozen=True)
class Planned:
    """One move of a generated stream: what was sent and what should become of it."""

    move_id: int
    angle: float
    kind: str
    tag: float  # the move's samples carry it: a window row can be traced to its move


def _data(tag: float, signal: str, n: int = N) -> np.ndarray:
    base = np.arange(n, dtype=float) + tag
    return base if signal == 'current' else -base


def _halves(p: Planned, stamp: float) -> list[MoveHalf]:
    """The halves sent for one planned move (one fault applied, or a repeat added)."""
    def half(signal: str, **over: Any) -> MoveHalf:
        values: dict[str, Any] = {'move_id': p.move_id, 'target_angle': p.angle,
                                  'sample_period': DT, 'stamp': stamp,
                                  'data': _data(p.tag, signal)}
        values.update(over)
        return MoveHalf.create(signal, **values)

    cur, enc = half('current'), half('encoder')
    k = p.kind
    if k == 'nan_current':
        data = _data(p.tag, 'current')
        data[N // 2] = math.nan
        cur = half('current', data=data)
    elif k == 'inf_encoder':
        data = _data(p.tag, 'encoder')
        data[-1] = -math.inf
        enc = half('encoder', data=data)
    elif k == 'nan_stamp':
        cur = half('current', stamp=math.nan)
    elif k == 'empty_current':
        cur = half('current', data=np.zeros(0))
    elif k == 'oversized_encoder':
        enc = half('encoder', data=np.zeros(10 * N))
    elif k == 'short_encoder':
        enc = half('encoder', data=np.zeros(4))
    elif k == 'lengths_differ':
        enc = half('encoder', data=_data(p.tag, 'encoder', N - 3))
    elif k == 'zero_angle':
        cur, enc = half('current', target_angle=0.0), half('encoder', target_angle=0.0)
    elif k == 'zero_period':
        enc = half('encoder', sample_period=0.0)
    elif k == 'negative_period':
        cur = half('current', sample_period=-DT)
    elif k == 'angles_disagree':
        enc = half('encoder', target_angle=2 * p.angle)
    elif k == 'bad_signal':
        cur = half('torque')
    if k == 'missing_encoder':
        return [cur]
    if k == 'missing_current':
        return [enc]
    out = [cur, enc]
    if k == 'repeat_current':
        out.append(cur)
    elif k == 'repeat_encoder':
        out.append(enc)
    return out


moves_strategy = st.lists(
    st.tuples(st.sampled_from([0.3, -0.3, 0.9]), st.sampled_from(KINDS)),
    min_size=1, max_size=40)


@st.composite
def streams(draw: st.DrawFn) -> tuple[list[Planned], list[MoveHalf]]:
    """Planned moves and the halves as they arrive (each up to 3 moves late)."""
    plan = [Planned(i, angle, kind, 1000.0 * (i + 1))
            for i, (angle, kind) in enumerate(draw(moves_strategy))]
    sent: list[tuple[float, int, MoveHalf]] = []
    for p in plan:
        for j, h in enumerate(_halves(p, 100.0 + p.move_id * MOVE_TIME)):
            delay = draw(st.floats(0.0, 2.99))
            sent.append((p.move_id + delay, 3 * p.move_id + j, h))
    sent.sort(key=lambda x: (x[0], x[1]))
    return plan, [h for _, _, h in sent]


def _feed(w: MoveWindower, items: list[MoveHalf]) -> tuple[list[Window], list[Rejection]]:
    windows: list[Window] = []
    rejections: list[Rejection] = []
    for h in items:
        windows.extend(w.add(h))
        rejections.extend(w.pop_rejections())
    windows.extend(w.flush(min_moves=1))
    rejections.extend(w.pop_rejections())
    return windows, rejections


def _check_windows(windows: list[Window], plan: dict[int, Planned]) -> dict[int, int]:
    """Each window row is its move's own samples, of the window's angle; count per move."""
    seen: dict[int, int] = {}
    for win in windows:
        assert win.current.shape == win.encoder.shape == (win.moves, N)
        for row, mid in enumerate(win.move_ids):
            p = plan[mid]
            assert p.angle == win.target_angle
            np.testing.assert_array_equal(win.current[row], _data(p.tag, 'current'))
            np.testing.assert_array_equal(win.encoder[row], _data(p.tag, 'encoder'))
            seen[mid] = seen.get(mid, 0) + 1
    return seen


def _is_repeat(r: Rejection) -> bool:
    return 'duplicate' in r.reason or 'repeat' in r.reason


@examples(300)
@given(streams(), st.integers(2, 5))
def test_every_move_is_windowed_or_set_aside_exactly_once(
        stream: tuple[list[Planned], list[MoveHalf]], window_size: int) -> None:
    plan_list, items = stream
    plan = {p.move_id: p for p in plan_list}
    w = MoveWindower(window_size=window_size, min_samples=8, max_samples=4 * N,
                     pair_timeout=0.1, time_jump=0.5)
    windows, rejections = _feed(w, items)
    windowed = _check_windows(windows, plan)
    set_aside: dict[int, list[str]] = {}
    for r in rejections:
        assert r.reason
        if not _is_repeat(r):
            set_aside.setdefault(r.move_id, []).append(r.reason)
    for p in plan_list:
        if p.kind in FAULTS:
            assert p.move_id not in windowed, p
            assert len(set_aside.get(p.move_id, [])) == 1, (p, set_aside.get(p.move_id))
        else:
            assert windowed.get(p.move_id) == 1, p
            assert p.move_id not in set_aside, (p, set_aside[p.move_id])
    repeats = [r.move_id for r in rejections if _is_repeat(r)]
    assert sorted(repeats) == sorted(p.move_id for p in plan_list if p.kind in REPEATS)
    full = [x for x in windows if not x.partial]
    assert all(x.moves == window_size for x in full)
    assert w.pending == w.open_windows == w.buffered_samples == 0
    assert w.moves_accepted == sum(windowed.values())
    assert w.moves_rejected == len(rejections)


@examples(200)
@given(streams(), st.integers(2, 4), st.integers(1, 3), st.integers(1, 2))
def test_tight_limits_evict_moves_once_and_never_also_window_them(
        stream: tuple[list[Planned], list[MoveHalf]], window_size: int, max_pending: int,
        max_windows: int) -> None:
    plan_list, items = stream
    plan = {p.move_id: p for p in plan_list}
    w = MoveWindower(window_size=window_size, min_samples=8, max_samples=4 * N,
                     pair_timeout=0.1, time_jump=0.5, max_pending=max_pending,
                     max_windows=max_windows)
    windows: list[Window] = []
    rejections: list[Rejection] = []
    for h in items:
        windows.extend(w.add(h))
        rejections.extend(w.pop_rejections())
        assert w.pending <= max_pending
        assert w.open_windows <= max_windows
    windows.extend(w.flush(min_moves=1))
    rejections.extend(w.pop_rejections())
    windowed = _check_windows(windows, plan)
    set_aside: dict[int, int] = {}
    for r in rejections:
        if not _is_repeat(r):
            set_aside[r.move_id] = set_aside.get(r.move_id, 0) + 1
    for p in plan_list:
        fate = windowed.get(p.move_id, 0) + set_aside.get(p.move_id, 0)
        assert fate == 1, (p, windowed.get(p.move_id), set_aside.get(p.move_id))
        if p.kind in FAULTS:
            assert p.move_id not in windowed
    assert w.moves_rejected == len(rejections)


@examples(60)
@given(st.integers(12, 30), st.integers(12, 30), st.integers(2, 6),
       st.lists(st.sampled_from([0.3, -0.3, 0.9]), min_size=1, max_size=3))
def test_replay_looping_back_never_mixes_passes(first: int, second: int, window_size: int,
                                                angles: list[float]) -> None:
    w = MoveWindower(window_size=window_size, min_samples=8, pair_timeout=0.02,
                     time_jump=0.05)
    windows: list[Window] = []
    rejections: list[Rejection] = []
    for pass_no, count in ((1, first), (2, second)):
        for i in range(count):
            tag = 1e6 * pass_no + 1000.0 * i
            p = Planned(i, angles[i % len(angles)], 'ok', tag)
            for h in _halves(p, 100.0 + i * MOVE_TIME):  # same ids and stamps each pass
                windows.extend(w.add(h))
                rejections.extend(w.pop_rejections())
    windows.extend(w.flush(min_moves=1))
    rejections.extend(w.pop_rejections())
    assert w.resets == 1
    for win in windows:
        passes = {int(row[0] // 1e6) for row in win.current}
        assert len(passes) == 1, win.move_ids
    discarded = [r for r in rejections if 'time jumped back' in r.reason]
    total = sum(x.moves for x in windows) + len(discarded)
    assert total == first + second
    assert len(rejections) == len(discarded)


# -- arbitrary message-like objects ---------------------------------------------------------

anything = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.floats(), st.text(max_size=5),
    st.binary(max_size=8), st.lists(st.floats(), max_size=5),
)
numbers = st.one_of(st.floats(), st.integers(-(2**64), 2**64), st.sampled_from([0.3, -0.3]))
data_values = st.one_of(
    hnp.arrays(np.float64, st.integers(0, 80)),
    hnp.arrays(np.float32, st.integers(0, 80), elements=st.floats(width=32)),
    hnp.arrays(np.int64, st.integers(0, 80)),
    hnp.arrays(np.complex128, st.integers(0, 8)),
    hnp.arrays(np.float64, hnp.array_shapes(min_dims=2, max_dims=3, max_side=6)),
    st.lists(st.one_of(st.floats(), st.text(max_size=2), st.none()), max_size=8),
    st.just(np.linspace(0.0, 1.0, 64)), st.just([[1.0, 2.0], [3.0]]), anything,
)


@st.composite
def message_likes(draw: st.DrawFn) -> tuple[Any, str]:
    """A MoveSamples-like object (duck typed like a rosbags message), fields arbitrary."""
    stamp = SimpleNamespace(sec=draw(st.one_of(st.integers(-(2**40), 2**40), anything)),
                            nanosec=draw(st.one_of(st.integers(0, 10**9), anything)))
    fields = {'header': SimpleNamespace(stamp=stamp),
              'move_id': draw(st.one_of(st.integers(0, 20), anything)),
              'target_angle': draw(numbers), 'sample_period': draw(numbers),
              'data': draw(data_values)}
    for name in list(fields):
        if draw(st.integers(0, 30)) == 0:
            del fields[name]
    signal = draw(st.sampled_from(['current', 'encoder', 'encoder ', '']))
    return SimpleNamespace(**fields), signal


def _stub_fit(window: Window) -> IdentificationResult:
    raise InvalidDataError(f'stub: {window.moves} moves')


@examples(200)
@given(st.lists(message_likes(), max_size=40))
def test_arbitrary_messages_give_halves_or_typed_errors(msgs: list[tuple[Any, str]]) -> None:
    outcomes: list[FitOutcome] = []
    warned: list[str] = []
    task = SysidTask(_stub_fit, outcomes.append, warn=warned.append,
                     windower={'window_size': 2, 'max_pending': 4, 'max_windows': 2},
                     warnings_per_second=1000)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')  # complex -> float casts warn; that is fine
            for msg, signal in msgs:
                try:
                    half = move_half_from_msg(msg, signal=signal)
                except InvalidDataError as err:
                    task.set_aside(str(err))
                    continue
                assert isinstance(half, MoveHalf)
                task.add(half)
                assert task.windower.pending <= 4
                assert task.windower.open_windows <= 2
            task.tick()
    finally:
        task.close(timeout=5.0)
    stats = task.stats()
    assert stats['windows_completed'] == stats['windows_identified'] + stats['windows_failed'] \
        + stats['windows_dropped'] + stats['windows_waiting']


# -- numerics entry points ------------------------------------------------------------------

floats_any = st.floats(allow_nan=True, allow_infinity=True)
weird_arrays = st.one_of(
    hnp.arrays(np.float64, hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=70),
               elements=floats_any),
    hnp.arrays(np.float64, st.tuples(st.integers(1, 4), st.integers(30, 90)),
               elements=st.floats(-1e6, 1e6)),
    st.lists(st.floats(), max_size=5), st.text(max_size=3), st.none(),
)
periods = st.one_of(st.sampled_from([DT, 1e-5, 1.0, 0.0, -DT]), floats_any)


def _typed_or_ok(call: Any, *args: Any, **kwargs: Any) -> Any:
    """Run ``call``; a GalvoSysidError is fine, any other exception fails the test."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        try:
            out = call(*args, **kwargs)
        except GalvoSysidError as err:
            if not str(err):
                pytest.fail(f'{type(err).__name__} without a message')
            event(f'{call.__name__}: {type(err).__name__}')
            return None
    event(f'{call.__name__}: result')
    return out


METHODS = ('paper-A', 'paper-B', 'refined')
MIN_SAMPLES = min_data_length(15, 15)
"""Shortest record validation accepts for the default ARX(15, 15) (75 samples)."""


@st.composite
def valid_windows(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """(M, N) current and encoder arrays that validation accepts (finite, one shape, long
    enough, a current and a move), otherwise arbitrary: part of a simulated window at any
    scale, with arbitrary values added or instead; a flat encoder gets a 3e-3 deg ramp and an
    all-zero current one non-zero sample, so that every drawn window is valid."""
    base_cur, base_enc = _base_window()
    m = draw(st.integers(2, base_cur.shape[0]))
    n = draw(st.integers(MIN_SAMPLES, 200))
    start = draw(st.integers(0, base_cur.shape[1] - n))
    cur = base_cur[:m, start: start + n] * 10.0 ** draw(st.floats(-6, 6))
    enc = base_enc[:m, start: start + n] * 10.0 ** draw(st.floats(-6, 6))
    arbitrary = hnp.arrays(np.float64, (m, n), elements=st.floats(-1e9, 1e9))
    mix = draw(st.sampled_from(['as simulated', 'plus arbitrary', 'arbitrary']))
    if mix == 'plus arbitrary':
        cur, enc = cur + draw(arbitrary), enc + draw(arbitrary)
    elif mix == 'arbitrary':
        cur, enc = draw(arbitrary), draw(arbitrary)
    if not np.any(cur):
        cur[0, n // 2] = 1.0
    if np.ptp(np.mean(enc - enc[:, :1], axis=0)) < MIN_ANGLE_SPAN:
        enc = enc + np.linspace(0.0, 3 * MIN_ANGLE_SPAN, n)
    event(f'window: {mix}')
    return cur, enc


@examples(60)
@given(valid_windows(), st.sampled_from(METHODS))
def test_identify_window_on_arbitrary_valid_windows(window: tuple[np.ndarray, np.ndarray],
                                                    method: str) -> None:
    """Arbitrary numbers in a valid window reach the fits: a result or a typed error."""
    cur, enc = window
    validate_records(cur, enc)  # the input is valid: what follows is the fit's doing
    result = _typed_or_ok(identify_window, cur, enc, sample_period=DT, method=method,
                          jackknife_groups=2 if method != 'refined' else 10)
    if result is not None:
        assert isinstance(result, IdentificationResult)
        assert result.moves + len(result.set_aside) == cur.shape[0]


INVALID = ('not numeric', 'none', 'one dimension', 'three dimensions', 'shapes differ',
           'one record', 'too short', 'nan everywhere', 'inf everywhere', 'zero current',
           'flat encoder', 'period of another scanner', 'zero period', 'negative period',
           'nan period', 'infinite period')
"""Ways a window is invalid, each with the typed error identify_window must raise."""


def _expected_error(fault: str) -> type[GalvoSysidError]:
    if fault == 'period of another scanner':
        return ModelMismatchError
    if fault.endswith('period'):
        return ConfigurationError
    return InvalidDataError


@examples(200)
@given(valid_windows(), st.sampled_from(INVALID), st.sampled_from(METHODS), st.data())
def test_identify_window_refuses_invalid_input_with_a_typed_error(
        window: tuple[np.ndarray, np.ndarray], fault: str, method: str,
        data: st.DataObject) -> None:
    """A valid window spoilt in one way that makes it invalid: the typed error of that
    fault with a message, never a result and never another exception."""
    cur, enc = window
    cur_in: Any = cur
    enc_in: Any = enc
    period = DT
    m, n = cur.shape
    if fault == 'not numeric':
        cur_in = data.draw(st.one_of(st.text(max_size=3), st.lists(st.text(max_size=2),
                                                                   min_size=1, max_size=3)))
    elif fault == 'none':
        enc_in = None
    elif fault == 'one dimension':
        cur_in, enc_in = cur[0], enc[0]
    elif fault == 'three dimensions':
        cur_in, enc_in = cur[None], enc[None]
    elif fault == 'shapes differ':
        enc_in = enc[:, : n - data.draw(st.integers(1, n - 1))]
    elif fault == 'one record':
        cur_in, enc_in = cur[:1], enc[:1]
    elif fault == 'too short':
        keep = data.draw(st.integers(0, MIN_SAMPLES - 1))
        cur_in, enc_in = cur[:, :keep], enc[:, :keep]
    elif fault in ('nan everywhere', 'inf everywhere'):
        bad = math.nan if fault.startswith('nan') else -math.inf
        enc_in = enc.copy()
        enc_in[np.arange(m), data.draw(st.integers(0, n - 1))] = bad
    elif fault == 'zero current':
        cur_in = np.zeros_like(cur)
    elif fault == 'flat encoder':
        enc_in = np.full_like(enc, data.draw(st.floats(-1e6, 1e6)))
    else:
        period = {'period of another scanner': 2 * DT, 'zero period': 0.0,
                  'negative period': -DT, 'nan period': math.nan,
                  'infinite period': math.inf}[fault]
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        with pytest.raises(_expected_error(fault)) as err:
            identify_window(cur_in, enc_in, sample_period=period, method=method,
                            jackknife_groups=2)
    assert str(err.value)


@examples(100)
@given(weird_arrays, weird_arrays, periods, st.integers(-2, 70), st.integers(-2, 70))
def test_paper_pipeline_fit_arx_validate_on_arbitrary_arrays(current: Any, encoder: Any,
                                                             period: float, na: int,
                                                             nb: int) -> None:
    _typed_or_ok(validate_records, current, encoder, na=na, nb=nb)
    _typed_or_ok(paper_pipeline, current, encoder, sample_period=period, na=na, nb=nb)
    u = np.asarray(current, dtype=object).ravel() if current is not None else current
    _typed_or_ok(fit_arx, u, encoder, sample_period=period, na=na, nb=nb)
    _typed_or_ok(estimate_delay, current, encoder, sample_period=period)


_BASE: dict[str, tuple[np.ndarray, np.ndarray]] = {}


def _base_window() -> tuple[np.ndarray, np.ndarray]:
    if not _BASE:
        _BASE['w'] = simulate_window(0.9, moves=6, seed=2)
    cur, enc = _BASE['w']
    return cur.copy(), enc.copy()


SPOILERS = ('scale_current', 'scale_encoder', 'constant_encoder', 'zero_rows', 'spike',
            'truncate', 'few_moves', 'noise_only', 'reverse', 'nan_sample', 'quantise')


@examples(150)
@given(st.lists(st.sampled_from(SPOILERS), min_size=1, max_size=3),
       st.floats(-300, 300), st.integers(0, 10**6),
       st.sampled_from(['paper-A', 'paper-B', 'refined']))
def test_identify_window_on_spoilt_simulated_windows(spoilers: list[str], exponent: float,
                                                     seed: int, method: str) -> None:
    """Near-valid windows reach the fits: they must end in a result or a typed error."""
    cur, enc = _base_window()
    rng = np.random.default_rng(seed)
    factor = 10.0 ** exponent
    with np.errstate(over='ignore', invalid='ignore'):
        cur, enc = _spoil(cur, enc, spoilers, factor, rng)
    result = _typed_or_ok(identify_window, cur, enc, sample_period=DT, method=method,
                          jackknife_groups=2)
    if result is not None:
        assert isinstance(result, IdentificationResult)
        # every move is either used or set aside by the screening, with a reason
        assert result.moves + len(result.set_aside) == cur.shape[0]
        assert all(0 <= i < cur.shape[0] and reason for i, reason in result.set_aside)


def _spoil(cur: np.ndarray, enc: np.ndarray, spoilers: list[str], factor: float,
           rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    for s in spoilers:
        if s == 'scale_current':
            cur = cur * factor
        elif s == 'scale_encoder':
            enc = enc * factor
        elif s == 'constant_encoder':
            enc = np.full_like(enc, 1.5)
        elif s == 'zero_rows':
            cur[: cur.shape[0] // 2] = 0.0
        elif s == 'spike':
            enc[rng.integers(enc.shape[0]), rng.integers(enc.shape[1])] = factor
        elif s == 'truncate':
            keep = int(rng.integers(1, cur.shape[1] + 1))
            cur, enc = cur[:, :keep], enc[:, :keep]
        elif s == 'few_moves':
            cur, enc = cur[:2], enc[:2]
        elif s == 'noise_only':
            cur = rng.standard_normal(cur.shape)
            enc = rng.standard_normal(enc.shape) * 1e-3
        elif s == 'reverse':
            cur, enc = cur[:, ::-1], enc[:, ::-1]
        elif s == 'nan_sample':
            cur[0, 0] = math.nan
        elif s == 'quantise':
            enc = np.round(enc / 0.5) * 0.5
    return cur, enc


def _result(values: list[float]) -> IdentificationResult:
    v = iter(values)
    return IdentificationResult(
        target_angle=next(v), moves=3, input_delay=next(v), lag_time_constant=0.0,
        k0=next(v), residues=(next(v), next(v), next(v)),
        natural_frequencies=(next(v), next(v), next(v)), damping_ratios=(next(v), next(v),
                                                                          next(v)),
        k0_std=next(v), residues_std=(next(v), next(v), next(v)),
        natural_frequencies_std=(next(v), next(v), next(v)),
        damping_ratios_std=(next(v), next(v), next(v)), fit_percent=next(v), method='refined')


result_values = st.lists(st.one_of(floats_any, st.sampled_from([0.0, 1.0, -1.0, 7e4])),
                         min_size=23, max_size=23)


@examples(150)
@given(st.lists(result_values, min_size=1, max_size=6))
def test_watchdog_and_pooling_on_arbitrary_results(values: list[list[float]]) -> None:
    results = [_result(v) for v in values]
    monitor = DriftMonitor()
    for i, r in enumerate(results):
        verdict = _typed_or_ok(monitor.assess, r, window_index=i)
        assert verdict is not None
        # MISMATCH: a k0 ten times off the reference's or more is another scanner or unit
        assert verdict.level in (OK, WARN, ERROR, MISMATCH)
        assert verdict.message
        verdict.to_dict()
    _typed_or_ok(pool_results, results)


stds = st.one_of(st.floats(0.0, 1e-3), floats_any, st.sampled_from([0.0, 5e-324, 1e-160, 1e160]))


@st.composite
def near_reference(draw: st.DrawFn) -> IdentificationResult:
    """A plausible result (reference x (1 + 1 %) noise) with arbitrary std."""
    ref = REFERENCE_MODEL
    means = [ref.k0, *ref.residues, *ref.natural_frequencies, *ref.damping_ratios]
    values = [m * (1 + draw(st.floats(-0.01, 0.01))) for m in means]
    spreads = [abs(m) * draw(stds) for m in means]
    return _result([0.9, 1.6e-5, values[0], *values[1:10], spreads[0], *spreads[1:10],
                    draw(st.floats(0.0, 100.0))])


@examples(100)
@given(st.lists(near_reference(), min_size=1, max_size=8))
def test_pooling_plausible_results_with_arbitrary_std(results: list[IdentificationResult]
                                                      ) -> None:
    pooled = _typed_or_ok(pool_results, results)
    if pooled is not None:
        assert pooled.moves == 3 * len(results)
        ref = REFERENCE_MODEL.natural_frequencies[0]
        assert abs(pooled.natural_frequencies[0] / ref - 1) <= 0.0100001


@examples(150)
@given(st.fixed_dictionaries({
    'target_angle': anything, 'moves': anything, 'input_delay': anything, 'k0': anything,
    'residues': anything, 'natural_frequencies': anything, 'damping_ratios': anything,
    'k0_std': anything, 'residues_std': anything, 'natural_frequencies_std': anything,
    'damping_ratios_std': anything, 'fit_percent': anything}))
def test_result_messages_with_arbitrary_fields(fields: dict[str, Any]) -> None:
    msg = SimpleNamespace(**fields)
    result = _typed_or_ok(result_from_msg, msg)
    if result is not None:
        verdict = _typed_or_ok(DriftMonitor().assess, result, window_index=0)
        assert verdict is not None


def test_reference_model_itself_is_ok() -> None:
    """The watchdog property above can fail: the reference judged against itself is OK."""
    ref = REFERENCE_MODEL
    values = [0.9, 1.6e-5, ref.k0, *ref.residues, *ref.natural_frequencies, *ref.damping_ratios,
              1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1e-5, 1e-5, 1e-5, 99.0]
    verdict = DriftMonitor().assess(_result(values), window_index=0)
    assert verdict.level == 0
    with pytest.raises(InvalidDataError):
        result_from_msg(SimpleNamespace(residues=[1.0]))
