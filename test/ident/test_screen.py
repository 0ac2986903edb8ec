"""Per-move screening: glitched moves are set aside, healthy ones (any scanner) are kept."""

from __future__ import annotations

import numpy as np
import pytest

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.ident import identify_window
from galvo_sysid.ident.screen import DEFAULT_SCREEN_LIMIT, screen_moves
from galvo_sysid.model import PAPER_MODEL, PSI, TAU, relative_errors
from galvo_sysid.sim.family import random_scanner
from galvo_sysid.sim.simulator import GalvoSimulator, simulate_window


def _window(seed: int = 3, angle: float = PSI) -> tuple[np.ndarray, np.ndarray]:
    return simulate_window(angle, moves=100, seed=seed)


@pytest.mark.parametrize('seed', range(4))
def test_healthy_windows_of_seeded_scanners_keep_every_move(seed: int) -> None:
    # the first move of a run starts from rest, the others with the previous move's ringing:
    # different initial conditions are not a glitch (the worst healthy deviation measured over
    # 60 family windows was 7.3 robust std; the limit is 10)
    sc = random_scanner(seed)
    sim = GalvoSimulator(config=sc.config, seed=70 + seed)
    for angle in (sc.reference_angle, 4 * sc.reference_angle):
        moves = list(sim.moves(angles=[angle], moves_per_angle=120))
        cur = np.array([m.current for m in moves if m.target_angle > 0])
        enc = np.array([m.encoder for m in moves if m.target_angle > 0])
        found = screen_moves(cur, enc, model=sc.model)
        assert found.reasons == (), found.reasons


def test_small_healthy_windows_keep_every_move() -> None:
    # 20 moves: the per-sample MAD of so few moves scatters by about 30 %, and taken alone it
    # set aside a healthy move of this window (10.5 robust std; 1 of 200 such windows, and
    # a live test's window of 20 moves); pooled with its neighbours it does not
    sim = GalvoSimulator(seed=20)
    moves = [m for m in sim.moves(angles=[0.9], moves_per_angle=200) if m.target_angle > 0]
    for start in (0, 20, 40):
        window = moves[start:start + 20]
        cur = np.array([m.current for m in window])
        enc = np.array([m.encoder for m in window])
        found = screen_moves(cur, enc, model=PAPER_MODEL)
        assert found.reasons == (), (start, found.reasons)


@pytest.mark.parametrize(('signal', 'size'), [('current', 100.0), ('encoder', 1.0),
                                              ('current', 3.0), ('encoder', 2e-3)])
def test_a_glitched_move_is_set_aside_and_the_fit_is_unharmed(signal: str, size: float) -> None:
    # reproduction of issue 12, defect 6: one spike in one move of 100 (100 A current,
    # 1 deg encoder) turned a healthy window into ERROR (k1 -62.6 %) or lost it
    cur, enc = _window()
    clean = identify_window(cur, enc, sample_period=TAU)
    (cur if signal == 'current' else enc)[10, 300] += size
    found = screen_moves(cur, enc, model=PAPER_MODEL)
    assert found.set_aside == (10,)
    res = identify_window(cur, enc, sample_period=TAU)
    assert res.moves == 99
    assert [i for i, _ in res.set_aside] == [10]
    for name, err in relative_errors(res.model, clean.model).items():
        std = res.std_by_name()[name] / abs(clean.model.parameters()[name])
        assert abs(err) < 0.5 * std + 1e-12, (name, err, std)


def test_non_finite_and_absurd_moves_are_set_aside() -> None:
    cur, enc = _window(seed=4)
    cur[3] *= 1e300
    enc[7, 5] = np.nan
    res = identify_window(cur, enc, sample_period=TAU)
    assert sorted(i for i, _ in res.set_aside) == [3, 7]
    assert 'NaN' in dict(res.set_aside)[7]
    assert 'beyond +-1e+06 (A or deg)' in dict(res.set_aside)[3]
    assert res.moves == 98


def test_a_window_of_absurdly_scaled_moves_is_refused_in_words() -> None:
    """Every move 1e300 times too large: the gross check compares moves with each other, so
    none stood out and the fit ended in 'unexpected LinAlgError: singular matrix'."""
    cur, enc = _window(seed=4)
    with pytest.raises(InvalidDataError, match=r'no move of the window is usable: the first has '
                                               r'samples beyond \+-1e\+06'):
        identify_window(cur * 1e300, enc, sample_period=TAU)


def test_a_small_glitch_below_the_limit_is_kept() -> None:
    # a glitch of a few noise levels is kept (it moves the average of 100 moves by well under
    # its noise), so the limit does not throw away healthy data
    cur, enc = _window(seed=5)
    noise = float(np.std(cur - cur.mean(axis=0)))
    cur[20, 200] += 2 * noise
    assert screen_moves(cur, enc, model=PAPER_MODEL).reasons == ()


def test_a_window_of_many_glitched_moves_is_refused() -> None:
    # more than a fifth of the moves broken: not single glitches to drop, the window is refused
    cur, enc = _window(seed=6)
    enc[:25, 200] += 0.01
    with pytest.raises(InvalidDataError, match='25 of 100 moves disagree'):
        screen_moves(cur, enc, model=PAPER_MODEL)
    assert len(screen_moves(cur[15:], enc[15:], model=PAPER_MODEL).reasons) == 10


def test_moves_of_another_angle_are_explained_by_the_model() -> None:
    # the test is of what the model cannot explain: another command is no glitch
    a_cur, a_enc = _window(seed=6, angle=3 * PSI)
    c_cur, c_enc = _window(seed=8, angle=1.3 * PSI)
    mixed = screen_moves(np.vstack([a_cur[:60], c_cur[:40]]),
                         np.vstack([a_enc[:60], c_enc[:40]]), model=PAPER_MODEL)
    assert mixed.reasons == ()


def test_screening_can_be_switched_off_and_checks_its_options() -> None:
    cur, enc = _window()
    cur[10, 300] += 100.0
    assert identify_window(cur, enc, sample_period=TAU, method='paper-A', screen_limit=0,
                           jackknife_groups=0).moves == 100
    assert DEFAULT_SCREEN_LIMIT == 10.0
    with pytest.raises(Exception, match='limit'):
        screen_moves(cur, enc, model=PAPER_MODEL, limit=-1.0)
