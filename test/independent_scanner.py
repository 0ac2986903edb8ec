"""An independent closed-loop galvo scanner simulator: data galvo_sysid's own code never made.

Every benchmark of the package's own simulator (:mod:`galvo_sysid.sim`) shares its
conventions with the identification: how the zero-order hold, the computation delay and the
amplifier lag are discretised, how the controller is designed, how the moves are shaped. This
module shares none of that code. It imports nothing from ``galvo_sysid``; the scanner is
written down from its physics:

- mechanics ``k0 / s^2 + sum_i k_i / (s^2 + 2 zeta_i omega_i s + omega_i^2)`` (deg per A) as a
  continuous state space (rigid body and one oscillator per mode), behind an amplifier lag
  ``1 / (1 + s T_l)`` as one more state; discretised under a zero-order hold by the matrix
  exponential of the augmented system (:func:`scipy.linalg.expm`), not by pole powers;
- the current command computed at sample k is held from sample k + d on (d samples of
  computation delay); a coloured current disturbance (first-order, std ``current_noise``)
  adds to it in the amplifier;
- the encoder reads the angle plus AR(2) noise (std ``encoder_noise`` counts), quantised to
  ``quantum`` deg; the controller sees that reading;
- the controller: PI x lead x second-order low-pass x a notch at each resonance the loop
  would otherwise ring at, each factor discretised on its own by Tustin's rule
  (:func:`scipy.signal.bilinear`) and run as a cascade of second-order sections; its
  crossover is lowered until the loop is stable with a gain margin of 1.6 (4 dB) (checked by running
  it);
- moves: minimum-jerk, cosine or sine-squared-velocity reference profiles with an
  acceleration feed-forward (its gain 0.8-1.1 of the truth), back and forth, each record
  starting where the last move left the plant (no reset between moves);
- what is recorded per move: the current command and the encoder reading, ``record``
  samples from the move's start, then a dwell that is not recorded.

:func:`random_scanner` draws a scanner from ranges of its own (not the package's family's);
:func:`simulate` runs it. The truth is :attr:`Scanner.k0` and so on, in the package's
parameter units (deg / (A s^2), rad/s). Used by ``test/ident/test_independent_scanner.py``
and ``benchmarks/independent_scanners.py`` (which put this directory on ``sys.path``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.signal

__all__ = ['PROFILES', 'Scanner', 'random_scanner', 'simulate']

PROFILES = ('minimum_jerk', 'cosine', 'sine_squared')
"""Reference profiles of a move (position over the move's duration)."""

_SETTLE_SAMPLES = 6000  # the stability check's run
_MARGIN = 1.6  # the gain margin asked of the loop (4 dB)


@dataclass(frozen=True)
class Scanner:
    """One scanner of the independent family (units: s, A, deg, rad/s).

    ``sections``: the controller's second-order sections (b0, b1, b2, a1, a2), in series.
    """

    seed: int
    sample_period: float
    k0: float
    residues: tuple[float, ...]
    omegas: tuple[float, ...]
    zetas: tuple[float, ...]
    delay: int
    lag: float
    record: int
    dwell: int
    move_samples: int
    profile: str
    feedforward_gain: float
    current_noise: float
    encoder_noise: float
    quantum: float
    crossover_hz: float
    notches: tuple[int, ...]
    sections: tuple[tuple[float, float, float, float, float], ...] = field(repr=False)

    def describe(self) -> str:
        """One line: period, record, modes [kHz], delay, controller, profile, noise."""
        modes = ', '.join(f'{w / (2 * math.pi) / 1e3:.2f}' for w in self.omegas)
        notch = ('notches at ' + ', '.join(str(i + 1) for i in self.notches)
                 if self.notches else 'no notch')
        return (f'T {self.sample_period * 1e6:.3g} us, N {self.record}, {len(self.omegas)} '
                f'mode(s) [{modes}] kHz, delay {self.delay} + lag '
                f'{self.lag / self.sample_period:.2f} T, crossover '
                f'{self.crossover_hz:.0f} Hz, {notch}, {self.profile} moves of '
                f'{self.move_samples} samples, noise {self.current_noise * 1e3:.1f} mA / '
                f'{self.encoder_noise:.1f} counts of {self.quantum:.2g} deg')


# -- the plant -------------------------------------------------------------------------------
def _plant(s: Scanner) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Phi, Gamma, c): x[k+1] = Phi x[k] + Gamma v[k] (v held over the sample), angle c x."""
    n = len(s.omegas)
    size = 2 + 2 * n + (1 if s.lag > 0 else 0)
    a = np.zeros((size, size))
    b = np.zeros(size)
    c = np.zeros(size)
    force = np.zeros(size)  # how the mechanics' input current enters
    a[0, 1] = 1.0
    force[1] = s.k0
    c[0] = 1.0
    for i, (k, w, z) in enumerate(zip(s.residues, s.omegas, s.zetas, strict=True)):
        j = 2 + 2 * i
        a[j, j + 1] = 1.0
        a[j + 1, j] = -w * w
        a[j + 1, j + 1] = -2.0 * z * w
        force[j + 1] = k
        c[j] = 1.0
    if s.lag > 0:  # the amplifier's current is the last state; the mechanics see it
        last = size - 1
        a[:, last] += force
        a[last, last] = -1.0 / s.lag
        b[last] = 1.0 / s.lag
    else:
        b = force
    aug = np.zeros((size + 1, size + 1))
    aug[:size, :size] = a * s.sample_period
    aug[:size, size] = b * s.sample_period
    e = scipy.linalg.expm(aug)
    return e[:size, :size], e[:size, size], c


# -- the controller --------------------------------------------------------------------------
def _tustin(num: list[float], den: list[float], t: float) -> tuple[float, ...]:
    """A continuous first- or second-order factor as one Tustin section (b0, b1, b2, a1, a2)."""
    bz, az = scipy.signal.bilinear(num, den, fs=1.0 / t)
    bz = np.concatenate([bz, np.zeros(3 - bz.size)]) / az[0]
    az = np.concatenate([az, np.zeros(3 - az.size)]) / az[0]
    return (float(bz[0]), float(bz[1]), float(bz[2]), float(az[1]), float(az[2]))


def _factors(s: Scanner, crossover_hz: float, notches: tuple[int, ...]) -> tuple[
        list[tuple[list[float], list[float]]], float]:
    """The controller's continuous factors (numerator, denominator) and its gain."""
    t = s.sample_period
    wc = 2 * math.pi * crossover_hz
    wz, wp, wi = wc / 3.0, wc * 3.0, wc / 8.0
    wl = min(6.0 * wc, 0.7 * math.pi / t)
    factors: list[tuple[list[float], list[float]]] = [
        ([1.0, wi], [1.0, 0.0]),                      # PI
        ([1.0 / wz, 1.0], [1.0 / wp, 1.0]),           # lead
        ([wl * wl], [1.0, 1.4 * wl, wl * wl]),        # low-pass
    ]
    for i in notches:
        w = s.omegas[i]
        factors.append(([1.0, 2 * 0.03 * w, w * w], [1.0, 2 * 0.5 * w, w * w]))
    # the gain: the loop's magnitude 1 at the crossover on the rigid body and the lag
    rigid = s.k0 / wc**2 / abs(1 + 1j * wc * s.lag)
    return factors, 1.0 / (_magnitude(factors, wc) * rigid)


def _magnitude(factors: list[tuple[list[float], list[float]]], w: float) -> float:
    mag = 1.0
    for num, den in factors:
        mag *= abs(np.polyval(num, 1j * w) / np.polyval(den, 1j * w))
    return mag


def _ringing(s: Scanner, crossover_hz: float) -> tuple[int, ...]:
    """The modes whose resonance peak, through the un-notched controller, reaches 0.3."""
    factors, gain = _factors(s, crossover_hz, ())
    return tuple(i for i, (k, w, z) in enumerate(zip(s.residues, s.omegas, s.zetas,
                                                      strict=True))
                 if gain * _magnitude(factors, w) * abs(k) / (2 * z * w * w) > 0.3)


def _design(s: Scanner, crossover_hz: float, notches: tuple[int, ...]) -> tuple[
        tuple[float, float, float, float, float], ...]:
    """The controller's sections for a crossover and the modes to notch."""
    factors, gain = _factors(s, crossover_hz, notches)
    sections = [_tustin(num, den, s.sample_period) for num, den in factors]
    b0, b1, b2, a1, a2 = sections[0]
    sections[0] = (b0 * gain, b1 * gain, b2 * gain, a1, a2)
    return tuple(sections)


class _Loop:
    """The closed loop, sample by sample (the controller sees the quantised reading)."""

    def __init__(self, s: Scanner, sections: tuple[tuple[float, ...], ...] | None = None) -> None:
        self.s = s
        self.phi, self.gamma, self.c = _plant(s)
        self.x = np.zeros(self.phi.shape[0])
        self.sections = s.sections if sections is None else sections
        self.z = [[0.0, 0.0] for _ in self.sections]
        self.queue = [0.0] * s.delay  # commands computed, not yet applied

    def amplifier_current(self, disturbance: float) -> float:
        """The current in the motor now: the lag's state, or without a lag the value held
        over this sample (the command due now plus the disturbance)."""
        if self.s.lag > 0:
            return float(self.x[-1])
        return (self.queue[0] if self.queue else 0.0) + disturbance

    def step(self, reference: float, feedforward: float, disturbance: float,
             noise: float) -> tuple[float, float]:
        """One sample: (command, reading); the plant then moves on by one sample."""
        angle = float(self.c @ self.x)
        q = self.s.quantum
        reading = q * round((angle + noise) / q) if q > 0 else angle + noise
        e = reference - reading
        for sec, z in zip(self.sections, self.z, strict=True):
            b0, b1, b2, a1, a2 = sec
            out = b0 * e + z[0]
            z[0] = b1 * e - a1 * out + z[1]
            z[1] = b2 * e - a2 * out
            e = out
        command = e + feedforward
        self.queue.append(command)
        applied = self.queue.pop(0) + disturbance
        self.x = self.phi @ self.x + self.gamma * applied
        return command, reading


def _stable(s: Scanner, sections: tuple[tuple[float, ...], ...]) -> bool:
    """Whether the loop, run noise-free and unquantised, settles after a step."""
    quiet = Scanner(**{**s.__dict__, 'quantum': 0.0, 'sections': sections})
    loop = _Loop(quiet)
    err = np.empty(_SETTLE_SAMPLES)
    for k in range(_SETTLE_SAMPLES):
        _, reading = loop.step(1.0, 0.0, 0.0, 0.0)
        err[k] = 1.0 - reading
        if not abs(err[k]) < 1e6:
            return False
    tail = err[-_SETTLE_SAMPLES // 6:]
    return bool(np.max(np.abs(tail)) < 1e-3 and np.max(np.abs(tail[-50:])) <= np.max(
        np.abs(err[-2 * len(tail): -len(tail)])) + 1e-12)


def _with_controller(s: Scanner) -> Scanner | None:
    """``s`` with a controller stable at 1.6 times its gain (crossover lowered as needed)."""
    fc = s.crossover_hz
    for _ in range(14):
        notches = _ringing(s, fc)
        sections = _design(s, fc, notches)
        raised = ((_MARGIN * sections[0][0], _MARGIN * sections[0][1],
                   _MARGIN * sections[0][2], sections[0][3], sections[0][4]), *sections[1:])
        if _stable(s, sections) and _stable(s, raised):
            return Scanner(**{**s.__dict__, 'crossover_hz': fc, 'notches': notches,
                              'sections': sections})
        fc *= 0.8
    return None


# -- the family ------------------------------------------------------------------------------
def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def random_scanner(seed: int) -> Scanner:
    """The scanner of ``seed`` (its own ranges; a draw without a stable loop is drawn again).

    Sample period 8-40 us; 1-4 modes between 1.5 kHz and the smaller of 25 kHz and 0.55 x
    Nyquist, at least 20 % apart, damping 0.003-0.05, residues of either sign 0.1-1.2 x k0;
    k0 1e6-1e7; 1-2 samples of delay and a lag of 0-0.8 T; records of 384-1,536 samples;
    crossover 0.6-1.5 kHz (at most 1 / (25 T)); moves of 20-80 samples (longer if the
    feed-forward would pass 8 A for a 0.3 deg move); current noise 2-15 mA; encoder noise
    0.5-3 counts of 19- to 23-bit encoders over 40 deg.
    """
    rng = np.random.default_rng([seed, 7_2026_11_27])
    for _ in range(60):
        t = float(f'{_log_uniform(rng, 8e-6, 40e-6):.3g}')
        f_max = min(25e3, 0.55 / (2 * t))
        n = int(rng.integers(1, 5))
        freqs = np.sort([_log_uniform(rng, 1.5e3, f_max) for _ in range(n)])
        if n > 1 and np.min(freqs[1:] / freqs[:-1]) < 1.2:
            continue
        k0 = _log_uniform(rng, 1e6, 1e7)
        record = round(_log_uniform(rng, 384, 1536))
        moves = int(rng.integers(20, 81))
        # a 0.3 deg minimum-jerk move of L samples peaks at 5.77 x 0.3 / (L T)^2 deg/s^2
        while 5.77 * 0.3 / (moves * t) ** 2 / k0 > 8.0:
            moves += 5
        if moves > record // 4:
            continue
        s = Scanner(
            seed=seed, sample_period=t, k0=k0,
            residues=tuple(float(rng.choice([-1.0, 1.0])) * _log_uniform(rng, 0.1, 1.2) * k0
                           for _ in range(n)),
            omegas=tuple(2 * math.pi * float(f) for f in freqs),
            zetas=tuple(_log_uniform(rng, 0.003, 0.05) for _ in range(n)),
            delay=int(rng.integers(1, 3)), lag=float(rng.uniform(0.0, 0.8)) * t,
            record=record, dwell=round(record * float(rng.uniform(0.15, 0.3))),
            move_samples=moves, profile=str(rng.choice(PROFILES)),
            feedforward_gain=float(rng.uniform(0.8, 1.1)),
            current_noise=float(rng.uniform(2e-3, 15e-3)),
            encoder_noise=float(rng.uniform(0.5, 3.0)),
            quantum=40.0 / 2 ** int(rng.integers(19, 24)),
            crossover_hz=min(float(rng.uniform(600.0, 1500.0)), 1.0 / (25 * t)),
            notches=(), sections=())
        done = _with_controller(s)
        if done is not None:
            return done
    msg = f'no stable scanner for seed {seed} in 60 draws'
    raise RuntimeError(msg)


# -- moves -----------------------------------------------------------------------------------
def _profile(name: str, samples: int) -> np.ndarray:
    """Position 0 -> 1 over ``samples`` samples (then 1)."""
    tau = np.clip(np.arange(samples + 1) / samples, 0.0, 1.0)
    if name == 'minimum_jerk':
        return np.asarray(tau**3 * (10 - 15 * tau + 6 * tau**2))
    if name == 'cosine':
        return np.asarray(0.5 - 0.5 * np.cos(np.pi * tau))
    if name == 'sine_squared':  # velocity sin^2: position tau - sin(2 pi tau) / (2 pi)
        return np.asarray(tau - np.sin(2 * np.pi * tau) / (2 * np.pi))
    msg = f'unknown profile {name!r}'
    raise ValueError(msg)


def simulate(s: Scanner, *, angles: list[float], moves_per_angle: int, seed: int,
             current: str = 'command', sensor_noise: float = 1e-3) -> dict[str, np.ndarray]:
    """``moves_per_angle`` moves of +a and -a in turn (+a first) for each a of ``angles``,
    one angle after the other, as recorded.

    ``current``: what the current record holds: ``'command'`` (the controller's output, as
    the package's model takes it: computation delay and amplifier lag between it and the
    mechanics) or ``'measured'`` (the amplifier's output current at each sample, disturbance
    included, plus white sensor noise of std ``sensor_noise`` [A]: no delay, and the current
    between two samples is the lag's smooth response, not a held value).

    Returns:
        ``current`` and ``encoder`` (moves, record), ``target_angle`` (moves,), and
        ``sample_period``: the arrays ``galvo-sysid import`` reads from a .npz file.
    """
    rng = np.random.default_rng([seed, s.seed, 11])
    t = s.sample_period
    loop = _Loop(s)
    start = 8  # samples of the record before the move begins
    shape = _profile(s.profile, s.move_samples)
    span = s.record + s.dwell
    moves = moves_per_angle * len(angles)
    total = moves * span + 2000
    # noise: the current disturbance first-order, the encoder's AR(2); both at their std
    a_i = 0.9
    dist = scipy.signal.lfilter([1.0], [1.0, -a_i], rng.standard_normal(total))
    dist *= s.current_noise / np.std(dist)
    r, theta = 0.8, math.pi / 4
    enc = scipy.signal.lfilter([1.0], [1.0, -2 * r * math.cos(theta), r * r],
                               rng.standard_normal(total))
    enc *= s.encoder_noise * s.quantum / np.std(enc)
    if current not in ('command', 'measured'):
        msg = f'current must be command or measured, got {current!r}'
        raise ValueError(msg)
    measured = current == 'measured'
    sensor = sensor_noise * rng.standard_normal(total)
    cur_out = np.empty((moves, s.record))
    enc_out = np.empty((moves, s.record))
    targets = np.empty(moves)
    position = 0.0
    k = 0
    for _ in range(2000):  # settle at rest first
        loop.step(position, 0.0, dist[k], enc[k])
        k += 1
    for m in range(moves):
        angle = angles[m // moves_per_angle]
        step = targets[m] = angle if m % 2 == 0 else -angle
        ref = position + step * np.concatenate([np.zeros(start), shape,
                                                np.ones(span - start - shape.size)])
        acc = np.zeros(span)
        acc[1:-1] = (ref[2:] - 2 * ref[1:-1] + ref[:-2]) / t**2
        ff = s.feedforward_gain * acc / s.k0
        for j in range(span):
            flowing = loop.amplifier_current(dist[k])
            command, reading = loop.step(float(ref[j]), float(ff[j]), dist[k], enc[k])
            k += 1
            if j < s.record:
                cur_out[m, j] = command if not measured else flowing + sensor[k]
                enc_out[m, j] = reading
        position += step
    return {'current': cur_out, 'encoder': enc_out, 'target_angle': targets,
            'sample_period': np.array(t)}
