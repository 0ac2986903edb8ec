"""Tests of the closed-loop galvano scanner simulator."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import (
    PAPER_ANGLES,
    PAPER_MODEL,
    REFERENCE_MODEL,
    TAU,
    Drift,
    InputDynamics,
    ModalModel,
    PlantModel,
    StepChange,
)
from galvo_sysid.model import simulate as simulate_plant
from galvo_sysid.sim.config import DEFAULT_ENCODER_RESOLUTION, Move, SimulatorConfig
from galvo_sysid.sim.simulator import GalvoSimulator, simulate_window

QUIET: dict[str, Any] = {'current_noise_std': 0.0, 'measurement_noise_std': 0.0,
                         'encoder_resolution': 0.0}
Q = DEFAULT_ENCODER_RESOLUTION


def _sim(seed: int = 0, **kwargs: Any) -> GalvoSimulator:
    return GalvoSimulator(config=SimulatorConfig(**kwargs), seed=seed)


def Resonance(natural_frequency: float, damping_ratio: float,
              residue: float) -> dict[str, float]:
    return {'natural_frequency': natural_frequency, 'damping_ratio': damping_ratio,
            'residue': residue}


def _effects(**kwargs: Any) -> PlantModel:
    """The paper's model with effects given by their physical quantities."""
    model = PAPER_MODEL
    for r in kwargs.pop('resonances', ()):
        model = model.with_effect('unmodeled_resonance', r)
    names = {'friction_current': ('coulomb_friction', 'friction_current'),
             'gain_ratio': ('gain_change', 'gain_ratio'),
             'current_limit': ('current_saturation', 'current_limit'),
             'pivot_frequency': ('pivot_stiffness', 'natural_frequency')}
    for key, value in kwargs.items():
        if key == 'dead_time':
            model = model.with_effect('input_delay', {'delay': model.base_delay + value})
        elif key != 'pivot_frequency' or value > 0:
            effect, param = names[key]
            model = model.with_effect(effect, {param: value})
    return model


def _open_loop(move: Move, model: ModalModel = REFERENCE_MODEL,
               dynamics: InputDynamics | None = None) -> np.ndarray:
    return simulate_plant(model, dynamics or InputDynamics(), move.current,
                          sample_period=TAU, y0=move.start_angle)


def _pair(sim: GalvoSimulator, angle: float) -> tuple[Move, Move]:
    return sim.run_move(angle), sim.run_move(-angle)


# --------------------------------------------------------------------------- the loop


def test_margins_are_positive_and_reasonable() -> None:
    m = _sim().margins()
    assert m.closed_loop_stable
    assert m.gain_margin_db > 10
    assert 40 < m.phase_margin < 60
    assert m.gain_crossover_frequency == pytest.approx(800, rel=0.01)
    # A delay-only effect eats phase but the loop stays well stable.
    m = _sim().margins(_effects(dead_time=TAU))
    assert m.closed_loop_stable
    assert m.phase_margin > 30


@pytest.mark.parametrize('angle', [0.03, 0.3, 3.0, -0.9])
def test_move_settles_at_its_target(angle: float) -> None:
    sim = _sim(**QUIET)
    sim.run_move(0.3)  # not from the very first state
    sim.run_move(-0.3)
    move = sim.run_move(angle)
    assert move.start_angle == 0.0
    assert move.target_angle == angle
    assert move.encoder.shape == move.current.shape == (512,)
    tail = move.encoder[-100:] - angle
    assert abs(tail.mean()) < 2e-5
    assert np.abs(tail).max() < 3e-4                # what rings on is the 11 kHz mode
    assert np.abs(move.current[-100:]).max() < 2e-3
    assert move.encoder[0] == pytest.approx(0.0, abs=1e-4)


def test_noisy_window_settles_on_average() -> None:
    cur, enc = simulate_window(0.3, moves=100, seed=2)
    assert cur.shape == enc.shape == (100, 512)
    assert enc[:, -100:].mean() == pytest.approx(0.3, abs=3e-5)
    assert np.abs(enc[:, :5]).max() < 2e-3          # each starts at rest at 0 deg


def test_open_loop_plant_reproduces_the_encoder() -> None:
    """The identification premise: plant.simulate(current) == encoder (noise off)."""
    sim = _sim(**QUIET)
    first = sim.run_move(0.3)                       # from exact rest: exact
    np.testing.assert_allclose(first.encoder, _open_loop(first), atol=1e-12)
    for _ in range(3):                              # later: only the ringing carried over
        move = sim.run_move(-0.3)
        assert np.abs(move.encoder - _open_loop(move)).max() < 2e-4


@pytest.mark.parametrize(('effects', 'model', 'dynamics'), [
    ({'dead_time': 0.37 * TAU}, REFERENCE_MODEL, InputDynamics(dead_time=0.37 * TAU)),
    ({'dead_time': 2 * TAU}, REFERENCE_MODEL, InputDynamics(dead_time=2 * TAU)),
    ({'gain_ratio': 1.2}, dataclasses.replace(
        REFERENCE_MODEL, k0=1.2 * REFERENCE_MODEL.k0,
        residues=tuple(1.2 * k for k in REFERENCE_MODEL.residues)), InputDynamics()),
    ({'resonances': (Resonance(2 * math.pi * 5000, 0.02, 2e5),)}, ModalModel(
        k0=REFERENCE_MODEL.k0, residues=(2e5, *REFERENCE_MODEL.residues),
        natural_frequencies=(2 * math.pi * 5000, *REFERENCE_MODEL.natural_frequencies),
        damping_ratios=(0.02, *REFERENCE_MODEL.damping_ratios)), InputDynamics()),
])
def test_linear_effects_are_the_augmented_plant(effects: dict[str, Any], model: ModalModel,
                                                dynamics: InputDynamics) -> None:
    move = _sim(plant=_effects(**effects), **QUIET).run_move(0.3)
    np.testing.assert_allclose(move.encoder, _open_loop(move, model, dynamics), atol=1e-12)
    nominal = _sim(**QUIET).run_move(0.3)
    assert np.abs(move.encoder - nominal.encoder).max() > 1e-5


# --------------------------------------------------------------------------- noise


def _first_move_residuals(seeds: range, **kwargs: Any) -> np.ndarray:
    """Encoder minus open-loop plant of the first move (from exact rest) = sensor noise."""
    out = []
    for seed in seeds:
        move = _sim(seed, **kwargs).run_move(0.3)
        out.append(move.encoder - _open_loop(move))
    return np.array(out)


def test_measurement_noise_level_and_colour() -> None:
    std, corner = 5e-5, 20e3
    res = _first_move_residuals(range(30), current_noise_std=0.0, encoder_resolution=0.0,
                                measurement_noise_std=std, measurement_noise_corner=corner)
    assert res.std() == pytest.approx(std, rel=0.05)
    lag1 = np.mean(res[:, 1:] * res[:, :-1]) / np.mean(res * res)
    assert lag1 == pytest.approx(math.exp(-2 * math.pi * corner * TAU), abs=0.04)
    white = _first_move_residuals(range(10), current_noise_std=0.0, encoder_resolution=0.0,
                                  measurement_noise_std=std, measurement_noise_corner=math.inf)
    assert abs(np.mean(white[:, 1:] * white[:, :-1]) / np.mean(white**2)) < 0.05


def test_quantisation_puts_the_encoder_on_its_grid() -> None:
    res = _first_move_residuals(range(10), current_noise_std=0.0, measurement_noise_std=2e-5)
    assert res.std() == pytest.approx(math.sqrt(2e-5**2 + Q**2 / 12), rel=0.08)
    move = _sim().run_move(0.3)
    counts = move.encoder / Q
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)


def test_current_noise_scales_as_configured() -> None:
    def scatter(std: float) -> np.ndarray:
        sim = _sim(3, measurement_noise_std=0.0, encoder_resolution=0.0, current_noise_std=std)
        return np.array([sim.run_move(0.3 * (-1) ** i).encoder for i in range(6)])

    clean = scatter(0.0)
    one, two = scatter(1e-3) - clean, scatter(2e-3) - clean
    np.testing.assert_allclose(two, 2 * one, atol=1e-12)
    assert 2e-5 < one.std() < 2e-4


def test_default_noise_is_visible_per_move_and_averages_out() -> None:
    cur, enc = simulate_window(0.3, moves=100, seed=4)
    enc_scatter = (enc - enc.mean(axis=0))[:, 100:].std()
    cur_scatter = (cur - cur.mean(axis=0))[:, 100:].std()
    assert 1e-4 < enc_scatter < 3e-4               # documented: about 1.7e-4 deg
    assert 5e-4 < cur_scatter < 3e-3               # documented: about 1.2 mA
    # The mean of 100 moves is ~10x cleaner than one move (Fig. 6).
    mean_a = enc[:50].mean(axis=0)
    mean_b = enc[50:].mean(axis=0)
    assert (mean_a - mean_b)[100:].std() < 0.25 * enc_scatter


# --------------------------------------------------------------------------- determinism, paths


def test_same_seed_same_moves_other_seed_other_moves() -> None:
    a = [m.encoder for m in _sim(7).moves(angles=[0.3], moves_per_angle=4)]
    b = [m.encoder for m in _sim(7).moves(angles=[0.3], moves_per_angle=4)]
    c = [m.encoder for m in _sim(8).moves(angles=[0.3], moves_per_angle=4)]
    np.testing.assert_array_equal(np.array(a), np.array(b))
    assert np.abs(np.array(a) - np.array(c)).max() > 1e-5


def test_batches_and_single_moves_agree() -> None:
    batched = list(_sim(5).moves(angles=[0.3, 0.6], moves_per_angle=4, batch=64))
    sim = _sim(5)
    single = [sim.run_move(m.target_angle) for m in batched]
    for a, b in zip(batched, single, strict=True):
        assert a.move_id == b.move_id
        np.testing.assert_allclose(a.current, b.current, atol=1e-9)
        np.testing.assert_allclose(a.encoder, b.encoder, atol=Q * 1.0001)
        assert np.mean(a.encoder == b.encoder) > 0.99


@pytest.mark.parametrize('plant', [
    PAPER_MODEL,
    _effects(dead_time=0.4 * TAU),
    _effects(pivot_frequency=2 * math.pi * 80, gain_ratio=0.85),
    _effects(resonances=(Resonance(2 * math.pi * 6000, 0.01, 1e5),)),
    dataclasses.replace(PAPER_MODEL, dynamics=InputDynamics(lag_time_constant=0.0)),
])
def test_fast_and_exact_paths_agree_without_quantisation(plant: PlantModel) -> None:
    kwargs = {'plant': plant, 'encoder_resolution': 0.0}
    fast = list(_sim(2, method='fast', **kwargs).moves(angles=[0.3, 3.0], moves_per_angle=2))
    exact = list(_sim(2, method='exact', **kwargs).moves(angles=[0.3, 3.0], moves_per_angle=2))
    for a, b in zip(fast, exact, strict=True):
        np.testing.assert_allclose(a.encoder, b.encoder, atol=1e-12)
        np.testing.assert_allclose(a.current, b.current, atol=1e-10)


def test_fast_and_exact_paths_agree_statistically_with_quantisation() -> None:
    def window(method: str) -> np.ndarray:
        sim = _sim(6, method=method)
        return np.array([m.encoder for m in sim.moves(angles=[0.3], moves_per_angle=60)][::2])

    fast, exact = window('fast'), window('exact')
    assert np.abs(fast.mean(axis=0) - exact.mean(axis=0))[60:].max() < 4e-5
    s_fast = (fast - fast.mean(axis=0))[:, 60:].std()
    s_exact = (exact - exact.mean(axis=0))[:, 60:].std()
    assert s_fast == pytest.approx(s_exact, rel=0.15)


# --------------------------------------------------------------------------- effects


def test_zero_magnitude_effects_change_nothing() -> None:
    nominal = [m.encoder for m in _sim(1, encoder_resolution=0.0).moves(
        angles=[0.3], moves_per_angle=4)]
    for plant in (_effects(friction_current=0.0, dead_time=0.0, gain_ratio=1.0,
                           pivot_frequency=0.0, current_limit=math.inf),
                  _effects(current_limit=1e9),
                  _effects(resonances=(Resonance(2 * math.pi * 5000, 0.02, 0.0),))):
        moves = [m.encoder for m in _sim(1, encoder_resolution=0.0, plant=plant).moves(
            angles=[0.3], moves_per_angle=4)]
        np.testing.assert_allclose(np.array(moves), np.array(nominal), atol=1e-12)


def test_friction_slows_small_moves_and_stops_them_short() -> None:
    nominal = _pair(_sim(**QUIET), 0.03)
    rough = _pair(_sim(plant=_effects(friction_current=0.01), **QUIET), 0.03)
    for clean, slow in zip(nominal, rough, strict=True):
        sign = np.sign(clean.target_angle)
        # Behind the nominal move while it moves, short of the target at the end.
        assert (sign * (clean.encoder[20:40] - slow.encoder[20:40])).min() > 0
        end = clean.start_angle + clean.target_angle
        assert sign * (end - slow.encoder[-20:].mean()) > 1e-4
        assert abs(end - clean.encoder[-20:].mean()) < 2e-5
    # Stuck at the end: the rotor stands still (the encoder only shows the 11 kHz ringing,
    # averaged out over 53 samples = 6 periods) while the integrator winds the current up.
    enc, cur = rough[1].encoder, rough[1].current
    assert abs(enc[-53:].mean() - enc[-159:-106].mean()) < 5e-6
    assert cur[-50:].mean() - cur[300:350].mean() < -1e-3


def _actual_current(u: np.ndarray, limit: float, fine: int) -> np.ndarray:
    """Amplifier current on a fine grid: u delayed one sample, first-order lag, clipped."""
    lag = 0.6 * TAU
    h = TAU / fine
    applied = np.repeat(np.concatenate([[0.0], u[:-1]]), fine)
    out = np.empty(applied.shape[0])
    i = 0.0
    e = math.exp(-h / 2 / lag)
    for k, a in enumerate(applied):       # value at the middle of each fine step
        mid = a + (i - a) * e
        out[k] = min(max(mid, -limit), limit)
        i = a + (i - a) * e * e
    return out


def test_saturation_clips_the_actual_current_not_the_record() -> None:
    limit, fine = 0.6, 128
    move = _sim(plant=_effects(current_limit=limit), **QUIET).run_move(3.0)
    assert np.abs(move.current).max() > limit * 1.3       # the command itself is not clipped
    current = _actual_current(move.current, limit, fine)
    mech = InputDynamics(computation_delay=0, lag_time_constant=0.0)
    y = simulate_plant(REFERENCE_MODEL, mech, current, sample_period=TAU / fine)[::fine]
    np.testing.assert_allclose(move.encoder, y, atol=1e-6)
    unclipped = _open_loop(move)
    assert np.abs(move.encoder - unclipped).max() > 1e-2
    # And the nominal scanner is slower to get there when clipped.
    nominal = _sim(**QUIET).run_move(3.0)
    assert nominal.encoder[100] > move.encoder[100]


def test_pivot_stiffness_pulls_back_against_a_holding_current() -> None:
    wp = 2 * math.pi * 60
    sim = _sim(plant=_effects(pivot_frequency=wp), **QUIET)
    move = sim.run_move(3.0)
    holding = 3.0 * wp**2 / REFERENCE_MODEL.k0
    assert move.current[-50:].mean() == pytest.approx(holding, rel=0.05)
    free = _sim(**QUIET).run_move(3.0)
    assert abs(free.current[-50:].mean()) < 1e-3 * holding
    # The spring pulls back: behind the nominal move right after it.
    assert (free.encoder[200:260] - move.encoder[200:260]).mean() > 1e-5


def test_gain_change_overshoots() -> None:
    hot = _sim(plant=_effects(gain_ratio=1.3), **QUIET).run_move(0.3)
    nominal = _sim(**QUIET).run_move(0.3)
    assert hot.encoder[60:120].max() - 0.3 > nominal.encoder[60:120].max() - 0.3 + 1e-3


def test_viscous_friction_damps_the_rigid_body_on_both_paths() -> None:
    """Viscous friction is linear: the fast path runs it and agrees with the exact one; a
    current proportional to the speed makes the fast moves lag behind."""
    plant = PAPER_MODEL.with_effect('viscous_friction', {'current_per_velocity': 1e-5})
    fast = _sim(plant=plant, **QUIET).run_move(3.0)
    exact = _sim(plant=plant, method='exact', **QUIET).run_move(3.0)
    np.testing.assert_allclose(fast.encoder, exact.encoder, atol=1e-9)
    nominal = _sim(**QUIET).run_move(3.0)
    assert (nominal.encoder[40:70] - fast.encoder[40:70]).min() > 5e-4
    assert fast.encoder[-20:].mean() == pytest.approx(3.0, abs=3e-3)


def test_cogging_torque_is_held_by_the_controller() -> None:
    """At rest the integrator holds the current that balances the cogging torque there."""
    cog = {'amplitude': 0.02, 'period': 0.7, 'phase': 0.3}
    plant = PAPER_MODEL.with_effect('cogging_torque', cog)
    sim = _sim(plant=plant, **QUIET)
    for target in (0.5, 0.4):
        sim.run_move(target - sim.position)
        move = sim.run_move(1e-6)         # settling on
        hold = -0.02 * math.sin(2 * math.pi * target / 0.7 + 0.3)
        assert abs(hold) > 0.01
        assert move.current[-30:].mean() == pytest.approx(hold, abs=1e-3)
        assert move.encoder[-30:].mean() == pytest.approx(target, abs=3e-4)


def test_encoder_cyclic_error_is_in_the_reading_not_the_shaft() -> None:
    """The controller servoes on the reading: the encoder settles on the target, the shaft
    at the angle whose reading that is (the open-loop plant of the current shows it)."""
    err = {'amplitude': 2e-3, 'period': 0.5, 'phase': 1.0}
    plant = PAPER_MODEL.with_effect('encoder_cyclic_error', err)
    sim = _sim(plant=plant, **QUIET)
    sim.run_move(0.0 + 1e-9)          # settle on the reading of 0
    move = sim.run_move(0.3)
    assert move.encoder[-30:].mean() == pytest.approx(0.3, abs=3e-5)
    shaft = float(plant.physics().true_angle(0.3))
    assert abs(shaft - 0.3) > 1e-3
    y = _open_loop(move)
    start = float(plant.physics().true_angle(move.encoder[0]))
    assert (y[-30:] - y[0] + start).mean() == pytest.approx(shaft, abs=2e-5)


def test_amplifier_bandwidth_is_the_lag() -> None:
    plant = PAPER_MODEL.with_effect('amplifier_bandwidth', {'bandwidth': 10e3})
    move = _sim(plant=plant, **QUIET).run_move(0.3)
    lag = InputDynamics(lag_time_constant=1 / (2 * math.pi * 10e3))
    np.testing.assert_allclose(move.encoder, _open_loop(move, dynamics=lag), atol=1e-9)
    assert np.abs(move.encoder - _open_loop(move)).max() > 1e-4


# --------------------------------------------------------------------------- plant changes


def test_drift_changes_the_plant_as_scheduled() -> None:
    drift = Drift('omega_1', -0.002, unit='move', start=4)
    sim = _sim(1, drifts=(drift,), **QUIET)
    ref = _sim(1, **QUIET)
    w1 = REFERENCE_MODEL.natural_frequencies[0]
    for i in range(8):
        assert sim.plant.natural_frequencies[0] == pytest.approx(
            w1 * (1 - 0.002 * max(i - 4, 0)))
        a, b = sim.run_move(0.3 * (-1) ** i), ref.run_move(0.3 * (-1) ** i)
        if i <= 4:
            np.testing.assert_array_equal(a.encoder, b.encoder)
        else:
            assert np.abs(a.encoder - b.encoder).max() > 1e-7
    per_second = _sim(drifts=(Drift('k0', 0.05, unit='second'),), **QUIET)
    for _ in range(3):
        per_second.run_move(0.3)
    assert per_second.plant.k0 == pytest.approx(
        REFERENCE_MODEL.k0 * (1 + 0.05 * 3 * 606 * TAU))


def test_step_change_at_a_move() -> None:
    step = StepChange('k0', 1.2, at=3, relative=True)
    sim = _sim(1, steps=(step,), **QUIET)
    ref = _sim(1, **QUIET)
    for i in range(5):
        a, b = sim.run_move(0.3 * (-1) ** i), ref.run_move(0.3 * (-1) ** i)
        if i < 3:
            np.testing.assert_array_equal(a.encoder, b.encoder)
        else:
            assert np.abs(a.encoder - b.encoder).max() > 1e-6
    assert sim.plant.k0 == pytest.approx(1.2 * REFERENCE_MODEL.k0)


def test_changes_while_iterating_apply_from_the_next_move() -> None:
    sim = _sim(9)
    it = sim.moves(angles=[0.3], moves_per_angle=10, batch=64)
    got = [next(it) for _ in range(3)]
    sim.add_step(StepChange('friction_current', 0.01, at=3))
    got += list(it)
    ref = _sim(9, steps=(StepChange('friction_current', 0.01, at=3),))
    expected = list(ref.moves(angles=[0.3], moves_per_angle=10))
    assert [m.move_id for m in got] == list(range(10))
    for a, b in zip(got, expected, strict=True):
        np.testing.assert_array_equal(a.encoder, b.encoder)
    assert sim.plant.friction_current == 0.01
    sim.clear_changes()
    assert sim.plant.friction_current == 0.0


def test_set_plant_replaces_the_base_plant() -> None:
    sim = _sim(**QUIET)
    sim.run_move(0.3)
    sim.set_plant(_effects(dead_time=TAU))
    assert sim.plant.dead_time == pytest.approx(TAU)
    move = sim.run_move(-0.3)
    assert move.move_id == 1
    with pytest.raises(ConfigurationError):
        sim.set_plant(_effects(gain_ratio=30.0))      # unstable loop: refused
    assert sim.plant.dead_time == pytest.approx(TAU)


# --------------------------------------------------------------------------- schedule, errors


def test_schedule_alternates_forward_and_return() -> None:
    sim = _sim()
    moves = list(sim.moves(angles=[0.3, 0.6], moves_per_angle=4))
    assert [m.target_angle for m in moves] == [0.3, -0.3, 0.3, -0.3, 0.6, -0.6, 0.6, -0.6]
    assert [m.start_angle for m in moves] == pytest.approx([0, 0.3, 0, 0.3, 0, 0.6, 0, 0.6])
    assert [m.move_id for m in moves] == list(range(8))
    np.testing.assert_allclose(np.diff([m.stamp for m in moves]), 606 * TAU)
    assert sim.config.moves_per_second == pytest.approx(165.0, rel=0.001)
    assert sim.time == pytest.approx(8 * 606 * TAU)
    assert sim.move_count == 8
    assert sim.position == pytest.approx(0.0)


def test_paper_schedule_runs() -> None:
    moves = list(_sim().moves(angles=PAPER_ANGLES, moves_per_angle=2))
    assert len(moves) == 38
    assert all(np.all(np.isfinite(m.encoder)) for m in moves)


@pytest.mark.parametrize('kwargs', [
    {'current_noise_std': -1.0},
    {'measurement_noise_std': math.nan},
    {'encoder_resolution': -1e-5},
    {'measurement_noise_corner': 0.0},
    {'record_length': 8},
    {'dwell_length': -1},
    {'substeps': 0},
    {'method': 'magic'},
    {'design': dataclasses.replace(PAPER_MODEL, sample_period=2e-5)},
    {'drifts': ('omega_1',)},
    {'plant': 'nominal'},
    {'plant': _effects(gain_ratio=30.0)},
])
def test_bad_configuration_raises(kwargs: dict[str, Any]) -> None:
    with pytest.raises(ConfigurationError):
        GalvoSimulator(config=SimulatorConfig(**kwargs))


def test_bad_moves_raise() -> None:
    sim = _sim()
    with pytest.raises(ConfigurationError):
        sim.run_move(25.0)                           # beyond +-20 deg
    with pytest.raises(ConfigurationError):
        sim.run_move(12.0)                           # does not fit in the record
    with pytest.raises(ConfigurationError):
        sim.run_move(math.nan)
    with pytest.raises(ConfigurationError):
        list(sim.moves(angles=[0.3], moves_per_angle=3))
    with pytest.raises(ConfigurationError):
        list(sim.moves(angles=[], moves_per_angle=2))
    with pytest.raises(ConfigurationError):
        _sim(method='fast', plant=_effects(friction_current=0.01)).run_move(0.3)
    with pytest.raises(ConfigurationError):
        simulate_window(0.3, moves=0)
    assert sim.move_count == 0                       # nothing was simulated
