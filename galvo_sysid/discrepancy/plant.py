"""The discrepancy workflow's open-loop plant: the moves of a plant driven by their current.

The workflow compares a model with measured moves without the controller: the model
(:class:`~galvo_sysid.model.physics.Physics`, a plant model with its effects acting) is
driven by each move's measured current from rest at its start angle. It shares the exact
zero-order hold and the delay split of :mod:`galvo_sysid.model.dynamics` with the simulator,
so it is not independent of it; both are checked against python-control's own sampling in
the tests.

The plant from the DSP's current command u [A] to the encoder angle y [deg]::

    u --pure delay--> amplifier lag --> i --clip(+-limit)--> * gain_ratio --(+ d)--> mechanics

    mechanics(s) = k0 / (s^2 + w_p^2) + sum_i k_i / (s^2 + 2 zeta_i omega_i s + omega_i^2)

where the pure delay is the computation delay plus any dead time (an ``input_delay`` effect
sets their total so that pure delay + lag = its ``delay``), w_p is the pivot stiffness (0 for
a free rigid body) and d is the Coulomb friction, as an equivalent current opposing the
velocity of the rigid-body coordinate (the mean rotation; its torque does not scale with
``gain_ratio``). Friction follows a stick-slip (Karnopp) law, decided once per sample with
the friction held over the sample: the rotor stays stuck while the friction needed to hold
it is at most ``friction_current``, otherwise it slides with the full friction against its
velocity; a stop within a sample ends stuck, a reversal splits the sample at the linearly
interpolated zero crossing. Saturation clips the amplifier current i, which the lag makes
exactly known inside a sample; the clipped part is taken at the midpoints of ``substeps``
sub-steps and held over each.

The linear part is exact (zero-order hold, a fractional delay split exactly inside the
sample): :class:`PlantSimulator` computes its pulse responses once and applies them by FFT
convolution to many records at once. A move starts at rest at its start angle y0 (with a
pivot spring, at the spring's equilibrium: the holding current y0 / (gain * static gain)
flows before the move).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy.signal import lfilter  # C: 4x galvo_sysid.filters' speed on many rows

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.model.dynamics import modal_state_space, split_delay, zoh
from galvo_sysid.model.terms import current_law

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

    from galvo_sysid.model.physics import Physics

__all__ = [
    'PlantSimulator',
    'clip_correction',
    'mode_free_responses',
    'mode_pulse_responses',
    'resonance_pulse_response',
]


class _Amplifier:
    """The amplifier current inside the samples: exact from the delay and the lag.

    Over sample k the applied command is u[k - w - 1] until ``split`` and u[k - w] after it
    (w whole samples and a fraction of pure delay); the lag's current at time t of the
    sample is a i[k] + b u[k - w - 1] + c u[k - w] with coefficients evaluated at the
    sub-step midpoints (``*_mid``) and at the sample's end (``*_end``).
    """

    def __init__(self, physics: Physics, sample_period: float, substeps: int) -> None:
        t = sample_period
        whole, frac = split_delay(physics.pure_delay, t)
        self.whole = whole
        split = frac * t
        mids = np.asarray((np.arange(substeps) + 0.5) * (t / substeps), dtype=np.float64)
        lag = physics.lag_time_constant
        self.lag = lag
        if lag > 0:
            def coeffs(tt: NDArray[np.float64]) -> tuple[
                    NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
                e_all = np.exp(-tt / lag)
                e1 = np.exp(-np.minimum(tt, split) / lag)
                e2 = np.exp(-np.maximum(tt - split, 0.0) / lag)
                return e_all, (1 - e1) * e2, 1 - e2

            self.a_mid, self.b_mid, self.c_mid = coeffs(mids)
            end = coeffs(np.array([t]))
            self.a_end, self.b_end, self.c_end = (float(v[0]) for v in end)
        else:
            self.a_mid = np.zeros(substeps)
            self.b_mid = np.asarray(mids < split, dtype=np.float64)
            self.c_mid = 1.0 - self.b_mid
            self.a_end = self.b_end = self.c_end = 0.0

    def samples(self, u: NDArray[np.float64]) -> tuple[
            NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(i at each sample's start, u[k - w - 1], u[k - w]) of records u (M, L) from rest."""
        m, n = u.shape
        w = self.whole
        hist = np.concatenate([np.zeros((m, w + 1)), u], axis=1)    # hist[:, j + w + 1] = u[j]
        u_old = hist[:, :n]
        u_new = hist[:, 1:n + 1]
        if self.lag > 0:
            i0 = np.asarray(lfilter([0.0, 1.0], [1.0, -self.a_end],
                                    self.b_end * u_old + self.c_end * u_new, axis=1),
                            dtype=np.float64)
        else:
            i0 = np.zeros_like(u)
        return i0, u_old, u_new

    def midpoints(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """(M, L, S) amplifier current at the sub-step midpoints of records u (M, L)."""
        i0, u_old, u_new = self.samples(u)
        return np.asarray(i0[..., None] * self.a_mid + u_old[..., None] * self.b_mid
                          + u_new[..., None] * self.c_mid, dtype=np.float64)


def clip_correction(current: NDArray[np.float64], physics: Physics, *, sample_period: float,
                    substeps: int = 8) -> NDArray[np.float64]:
    """Torque current the amplifier's limit takes away, averaged over each sample (M, L).

    An approximation (the correction held over whole samples) for the ringing that clipped
    moves leave behind; zero without a limit. Records start from rest.
    """
    lim = physics.current_limit
    if not math.isfinite(lim):
        return np.zeros_like(current)
    i_mid = _Amplifier(physics, sample_period, substeps).midpoints(current)
    return np.asarray(physics.gain_ratio * (np.clip(i_mid, -lim, lim) - i_mid).mean(axis=-1),
                      dtype=np.float64)


def resonance_pulse_response(physics: Physics, *, sample_period: float, length: int,
                             applied: bool = False) -> NDArray[np.float64]:
    """Pulse response (length,) of the resonant modes alone (no rigid body, no pivot).

    From a one-sample command pulse through the delay, the lag and the gain, or, with
    ``applied``, from a torque current held over one sample.
    """
    if not physics.residues:
        return np.zeros(length)
    kw = ({'gain': 1.0, 'lag': 0.0, 'delay': 0.0} if applied else
          {'gain': physics.gain_ratio, 'lag': physics.lag_time_constant,
           'delay': physics.pure_delay})
    h = mode_pulse_responses(physics.natural_frequencies, physics.damping_ratios,
                             sample_period=sample_period, length=length, **kw)
    return np.asarray(np.asarray(physics.residues) @ h, dtype=np.float64)


def _fft_length(n: int) -> int:
    return 1 << (2 * n - 1).bit_length()


class PlantSimulator:
    """Open-loop simulation of one plant, move by move, from rest at each start angle.

    Args:
        physics: The plant.
        sample_period: Sampling period [s].
        length: Samples per record.
        substeps: Sub-steps per sample over which saturation is evaluated.
    """

    def __init__(self, physics: Physics, *, sample_period: float, length: int,
                 substeps: int = 32) -> None:
        if not (math.isfinite(sample_period) and sample_period > 0):
            raise ConfigurationError('sample_period must be positive and finite')
        if length < 4:
            raise ConfigurationError('records must have at least 4 samples')
        self.physics = physics
        self.sample_period = sample_period
        self.length = length
        self.substeps = substeps if math.isfinite(physics.current_limit) else 1
        ph = physics
        gains = [ph.k0, *ph.residues]
        freqs = [ph.pivot_frequency, *ph.natural_frequencies]
        damps = [0.0, *ph.damping_ratios]
        off = 1 if ph.lag_time_constant > 0 else 0
        # drive: the mechanics' input per unit torque current
        a, b_u, drive, c = modal_state_space(gains=gains, frequencies=freqs, dampings=damps,
                                             lag_time_constant=ph.lag_time_constant,
                                             input_gain=ph.gain_ratio,
                                             rigid_damping=ph.rigid_damping)
        n = a.shape[0]
        self._a, self._c, self._drive, self._off = a, c, drive, off
        t = sample_period
        self._phi, _ = zoh(a, b_u[:, None], t)
        # Pulse response of the command: unit u[0] applied over [D, D + T).
        whole, frac = split_delay(ph.pure_delay, t)
        self._whole, self._frac = whole, frac
        states = np.zeros((length + 2, n))
        if frac > 0:
            phi_rest, g_part = zoh(a, b_u[:, None], (1 - frac) * t)
            _, g_full = zoh(a, b_u[:, None], t)
            first = whole + 1
            if first < length + 2:
                states[first] = g_part[:, 0]
            x = phi_rest @ g_full[:, 0]
            start = whole + 2
        else:
            _, g_full = zoh(a, b_u[:, None], t)
            x = g_full[:, 0]
            start = whole + 1
        for k in range(start, length + 2):
            states[k] = x
            x = self._phi @ x
        self._u_states = states                  # (N + 2, n): state at k from u[0] = 1
        self._h_y = states @ c
        # Held responses of a current entering the mechanics directly (friction, saturation).
        self._held: dict[int, NDArray[np.float64]] = {}
        self._fr: NDArray[np.float64] | None = None

    # ------------------------------------------------------------------ linear part

    def _held_drive(self, substeps: int) -> NDArray[np.float64]:
        """(n, S): state at the sample's end from a unit current held over sub-step j."""
        if substeps not in self._held:
            h = self.sample_period / substeps
            phi_h, g_h = zoh(self._a, self._drive[:, None], h)
            cols = []
            x = g_h[:, 0]
            for _ in range(substeps):   # sub-step S-1-j is followed by j more sub-steps
                cols.append(x)
                x = phi_h @ x
            self._held[substeps] = np.stack(cols[::-1], axis=1)
        return self._held[substeps]

    def _from_increments(self, inc: NDArray[np.float64], length: int, *,
                         velocity: bool = False) -> NDArray[np.float64]:
        """Angle (R, length) from state increments inc (R, N, n) added at each sample's end.

        With ``velocity`` also the rigid body's position and velocity: (R, 3, length).
        """
        r, n, _ = inc.shape
        phi_t = self._phi.T
        eye = np.eye(self._a.shape[0])
        rows = [self._c] if not velocity else [self._c, eye[self._off], eye[self._off + 1]]
        obs = np.stack(rows, axis=1)                                # (n, 1 or 2)
        out = np.zeros((r, obs.shape[1], length))
        active = np.flatnonzero(np.any(inc != 0, axis=(0, 2)))
        if active.size == 0:
            return out if velocity else out[:, 0]
        x = np.zeros((r, self._a.shape[0]))
        for k in range(int(active[0]), length):
            out[:, :, k] = x @ obs
            x = x @ phi_t
            if k < n:
                x += inc[:, k]
        return out if velocity else out[:, 0]

    def _friction_response(self) -> NDArray[np.float64]:
        """(N,) angle from a unit current held over sample 0, entering the mechanics."""
        if self._fr is None:
            x = self._held_drive(1)[:, 0]
            out = np.zeros(self.length)
            for k in range(1, self.length):
                out[k] = self._c @ x
                x = self._phi @ x
            self._fr = out
        return self._fr

    def _convolve(self, h: NDArray[np.float64], x: NDArray[np.float64],
                  length: int) -> NDArray[np.float64]:
        """Causal convolution of (M, L) records with a pulse response, first ``length``."""
        nfft = _fft_length(max(h.shape[0], x.shape[-1], length))
        out = np.fft.irfft(np.fft.rfft(x, nfft, axis=-1) * np.fft.rfft(h, nfft), nfft, axis=-1)
        return np.asarray(out[..., :length], dtype=np.float64)

    def rigid_start(self, start: NDArray[np.float64]) -> NDArray[np.float64]:
        """The rigid-body coordinate's angle [deg] at rest at the shaft angle ``start``.

        Without a pivot spring the modes carry no torque at rest, so it is the shaft angle;
        with one, the held torque deflects the modes statically too.
        """
        ph = self.physics
        if ph.pivot_frequency <= 0:
            return np.array(start, dtype=np.float64)
        return np.asarray(start * (ph.k0 / ph.pivot_frequency**2) / ph.static_gain(),
                          dtype=np.float64)

    def holding_current(self, start: NDArray[np.float64]) -> NDArray[np.float64]:
        """Command that holds the plant at rest at the shaft angle ``start`` [deg]: against
        the pivot spring (0 without one), the cogging torque and the proposed terms' current
        there (those of the current itself solved for by fixed-point iteration)."""  # noqa: D205, D209
        ph = self.physics
        torque = (np.zeros_like(start) if ph.pivot_frequency <= 0 else
                  start / ph.static_gain())
        if ph.cogging_amplitude:
            torque = torque - ph.cogging(self.rigid_start(start), 0.0)
        u = np.asarray(torque / ph.gain_ratio, dtype=np.float64)
        if ph.current_terms:
            p0 = self.rigid_start(start)
            for _ in range(100):
                new = (torque - ph.term_current(p0, 0.0, 0.0, u)) / ph.gain_ratio
                done = float(np.max(np.abs(new - u), initial=0.0)) <= 1e-15 * (
                    1.0 + float(np.max(np.abs(new), initial=0.0)))
                u = np.asarray(new, dtype=np.float64)
                if done:
                    break
        return u

    def true_start(self, start: ArrayLike) -> NDArray[np.float64]:
        """The shaft angle whose encoder reading is ``start`` (itself without a cyclic error)."""
        return self.physics.true_angle(start)

    # ------------------------------------------------------------------ simulate

    def simulate(self, current: ArrayLike, start: ArrayLike, *,
                 extra: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """Simulate records from rest at their start angles.

        Args:
            current: Commanded current [A], (M, N) or (N,) with N = ``length``.
            start: Start angle(s) as the encoder reads them [deg], scalar or (M,).
            extra: A shaft angle (M, N) added before the encoder reads it (the ringing that
                previous moves leave, see :meth:`Comparison.carry`).

        Returns:
            The encoder angle [deg], shaped like ``current``.
        """
        u_in = np.asarray(current, dtype=float)
        u = np.atleast_2d(u_in)
        if u.ndim != 2 or u.shape[1] != self.length:
            raise InvalidDataError(f'current must have {self.length} samples per record')
        if not np.all(np.isfinite(u)):
            raise InvalidDataError('current contains NaN or Inf')
        ph = self.physics
        reading = np.broadcast_to(np.asarray(start, dtype=float), (u.shape[0],))
        y0 = self.true_start(reading) if ph.reading_error else reading.copy()
        u_eq = self.holding_current(y0)
        du = u - u_eq[:, None]
        n_len = self.length
        y = self._convolve(self._h_y, du, n_len) + y0[:, None]
        if ph.linear:
            if extra is not None:
                y += extra.reshape(y.shape)
            return np.asarray(y.reshape(u_in.shape), dtype=np.float64)
        rigid = None
        torques = ph.friction_current > 0 or ph.cogging_amplitude > 0 or ph.current_terms
        if math.isfinite(ph.current_limit):
            rows, inc = self._saturation(du, u_eq)
            if rows.size:
                out = self._from_increments(inc, n_len + 1, velocity=True)
                y[rows] += out[:, 0, :n_len]
                if torques:
                    rigid = np.zeros((u.shape[0], 2, n_len + 1))
                    rigid[rows] = out[:, 1:]
        if torques:
            off = self._off
            v_lin = self._convolve(self._u_states[:, off + 1], du, n_len + 1)
            p_lin = (self._convolve(self._u_states[:, off], du, n_len + 1)
                     if ph.cogging_amplitude or ph.current_terms else np.zeros_like(v_lin))
            if rigid is not None:
                p_lin += rigid[:, 0]
                v_lin += rigid[:, 1]
            d = self._torques(p_lin, v_lin, self.rigid_start(y0), u, u_eq)
            y += self._convolve(self._friction_response(), d, n_len)
        if extra is not None:
            y += extra.reshape(y.shape)
        if ph.reading_error:
            y = ph.reading(y)
        return np.asarray(y.reshape(u_in.shape), dtype=np.float64)

    def _saturation(self, du: NDArray[np.float64], u_eq: NDArray[np.float64]) -> tuple[
            NDArray[np.intp], NDArray[np.float64]]:
        """Records that clip, and their state increments (R, N, n) from the clipped current.

        The amplifier current inside a sample is a convex combination of its value at the
        sample's start and the two commands applied during the sample, so only samples where
        one of those exceeds the limit are evaluated.
        """
        ph = self.physics
        n = du.shape[1]
        lim = ph.current_limit
        amp = _Amplifier(ph, self.sample_period, self.substeps)
        i0, u_old, u_new = amp.samples(du)
        bound = np.maximum(np.maximum(np.abs(i0), np.abs(u_old)), np.abs(u_new))
        active = bound + np.abs(u_eq)[:, None] > lim
        rows = np.flatnonzero(active.any(axis=1))
        inc = np.zeros((rows.size, n, self._a.shape[0]))
        if rows.size:
            r_idx, k_idx = np.nonzero(active[rows])
            src = rows[r_idx]
            i_mid = (i0[src, k_idx, None] * amp.a_mid + u_old[src, k_idx, None] * amp.b_mid
                     + u_new[src, k_idx, None] * amp.c_mid + u_eq[src, None])
            d = ph.gain_ratio * (np.clip(i_mid, -lim, lim) - i_mid)          # (A, S)
            inc[r_idx, k_idx] = d @ self._held_drive(self.substeps).T
        return rows, inc

    def _torques(self, p_lin: NDArray[np.float64], v_lin: NDArray[np.float64],
                 p_start: NDArray[np.float64], u: NDArray[np.float64],
                 u_eq: NDArray[np.float64]) -> NDArray[np.float64]:
        """Friction, cogging and proposed terms' currents (M, N) held per sample.

        p_lin, v_lin (M, N + 1) are the rigid body's position (relative to its start
        ``p_start``) and velocity without these currents; their own share of the rigid body's
        position and velocity evolves with its one-sample transition. The cogging torque of
        the position and velocity at each sample's start (less its value at the start, which
        the holding current takes) acts first, with the proposed terms' current (of that
        position and velocity, the velocity change over the previous sample and the command u
        (M, N), less its value at rest at the start with the holding current u_eq (M,));
        Coulomb friction then follows a stick-slip
        law: the rotor stays stuck while the friction needed to hold it is at most
        ``friction_current``, otherwise it slides with the full friction against its
        velocity; a stop within a sample ends stuck, a reversal splits the sample at the
        linearly interpolated zero crossing.
        """
        ph = self.physics
        f = ph.friction_current
        off = self._off
        phi = self._phi[off:off + 2, off:off + 2]
        g = self._held_drive(1)[off:off + 2, 0]        # rigid-body state after one sample
        g_p, g_v = float(g[0]), float(g[1])
        limit = f * g_v                                 # largest velocity friction can stop
        spring = ph.pivot_frequency > 0 or ph.viscous_coefficient > 0
        cogging = ph.cogging_amplitude > 0
        terms = ph.current_terms
        moving = spring or cogging or terms          # the currents' share of position matters
        p00, p01, p10, p11 = (float(x) for x in phi.ravel())
        v_t = np.ascontiguousarray(v_lin.T)
        p_t = np.ascontiguousarray(p_lin.T + p_start)
        hold = ph.cogging(p_start, 0.0) if cogging else 0.0
        hold_terms = ph.term_current(p_start, 0.0, 0.0, u_eq) if terms else 0.0
        term_law = current_law(dict(ph.terms))
        u_t = np.ascontiguousarray(u.T)
        m, n1 = v_lin.shape
        v_last = np.zeros(m)
        t = self.sample_period
        n = n1 - 1
        sp = np.zeros(m)                                # the currents' share of position
        sv = np.zeros(m)                                # ... and of velocity
        stuck = np.ones(m, dtype=bool)                  # at rest at the start
        d = np.empty((n, m))
        with np.errstate(divide='ignore', invalid='ignore'):
            for k in range(n):
                v0 = v_t[k] + sv
                dc = ph.cogging(p_t[k] + sp, v0) - hold if cogging else 0.0
                if terms:
                    dc = dc + (term_law(p_t[k] + sp, v0, (v0 - v_last) / t, u_t[k])
                               - hold_terms)
                    v_last = v0
                if moving:
                    fv = p10 * sp + p11 * sv + g_v * dc
                    sp = p00 * sp + p01 * sv + g_p * dc
                else:
                    fv = sv
                if f <= 0:
                    sv = fv
                    d[k] = dc
                    continue
                v_free = v_t[k + 1] + fv
                # sliding (or breaking away) against the velocity
                sgn = np.sign(np.where(stuck, v_free, v0))
                slide = -f * sgn
                v_end = v_free + g_v * slide
                stop = (stuck | (v_end * sgn <= 0)) & (np.abs(v_free) <= limit)
                # a reversal inside the sample: friction flips at the interpolated zero
                reverse = ~stuck & ~stop & (v_end * sgn <= 0)
                dk = np.where(stop, -v_free / g_v,
                              np.where(reverse, slide * (v0 + v_end) / (v0 - v_end), slide))
                sv = np.where(stop, -v_t[k + 1], fv + g_v * dk)
                if moving:
                    sp = sp + g_p * dk
                stuck = stop
                d[k] = dk + dc
        return np.ascontiguousarray(d.T)


def mode_pulse_responses(natural_frequencies: ArrayLike, damping_ratios: ArrayLike, *,
                         gain: float = 1.0, lag: float = 0.0, delay: float = 0.0,
                         sample_period: float, length: int) -> NDArray[np.float64]:
    """Pulse responses of single modes 1 / (s^2 + 2 zeta omega s + omega^2), many at once.

    The command is a unit pulse u[0] = 1 held for one sample, delayed by ``delay`` [s],
    through the amplifier lag, times ``gain`` (closed form, same as :class:`PlantSimulator`
    for a plant with only that mode).

    Args:
        natural_frequencies: omega [rad/s], shape (P,).
        damping_ratios: zeta in (0, 1), shape (P,).
        gain: Torque constant ratio.
        lag: Amplifier lag [s].
        delay: Pure delay [s].
        sample_period: Sampling period [s].
        length: Samples.

    Returns:
        (P, length) angle per unit residue.
    """
    w = np.atleast_1d(np.asarray(natural_frequencies, dtype=float))
    z = np.atleast_1d(np.asarray(damping_ratios, dtype=float))
    if np.any(z <= 0) or np.any(z >= 1) or np.any(w <= 0):
        raise ConfigurationError('modes need omega > 0 and 0 < zeta < 1')
    wd = w * np.sqrt(1 - z * z)
    p1 = -z * w + 1j * wd
    p2 = np.conj(p1)
    poles = [p1, p2]
    if lag > 0:
        p3 = np.full_like(p1, -1.0 / lag)
        poles.append(p3)
        residues = [gain / (lag * (p1 - p2) * (p1 - p3)), gain / (lag * (p2 - p1) * (p2 - p3)),
                    gain / (lag * (p3 - p1) * (p3 - p2))]
    else:
        residues = [gain / (p1 - p2), gain / (p2 - p1)]
    dc = gain / (w * w)
    t = np.asarray(np.arange(length) * sample_period, dtype=np.float64)

    def step(tau: NDArray[np.float64]) -> NDArray[np.float64]:
        tt = np.maximum(tau, 0.0)[None, :]
        out = np.full((w.shape[0], tau.shape[0]), 0.0, dtype=complex) + dc[:, None]
        for p, r in zip(poles, residues, strict=True):
            out += (r / p)[:, None] * np.exp(p[:, None] * tt)
        return np.where(tau[None, :] > 0, out.real, 0.0)

    late: NDArray[np.float64] = step(t - delay - sample_period)
    return np.asarray(step(t - delay) - late, dtype=np.float64)


def mode_free_responses(natural_frequencies: ArrayLike, damping_ratios: ArrayLike, *,
                        sample_period: float, length: int) -> NDArray[np.float64]:
    """(P, 2, length): a mode's decaying cosine and sine, the span of its free responses."""
    w = np.atleast_1d(np.asarray(natural_frequencies, dtype=float))
    z = np.atleast_1d(np.asarray(damping_ratios, dtype=float))
    t = np.arange(length) * sample_period
    wd = (w * np.sqrt(np.maximum(1 - z * z, 0.0)))[:, None]
    env = np.exp(-(z * w)[:, None] * t[None, :])
    return np.stack([env * np.cos(wd * t), env * np.sin(wd * t)], axis=1)
