"""The closed loop of one plant: its matrices, the fast linear path and the exact path.

:class:`ClosedLoop` is built per plant (the simulator caches it): the sampled plant, the DSP's
command register (computation delay), the controller state, and, for the nonlinear effects,
the exact per-sample update (:meth:`ClosedLoop.exact_move`: the quantiser in the loop, the
amplifier's current limit evaluated on sub-steps, Coulomb friction as a stick-slip law, the
cogging torque of the rigid body's angle held over each sample, the encoder's cyclic error
in the reading, the discrepancy fallback's proposed terms).
:class:`FastBlock` holds the Markov parameters of the linear closed loop over one move, so a
batch of moves is matrix products and FFT convolutions.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.sampling import ContinuousPlant, sample_plant
from galvo_sysid.model.terms import current_law, term_reading

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from galvo_sysid.model.physics import Physics
    from galvo_sysid.sim.config import SimulatorConfig
    from galvo_sysid.sim.controller import Controller

__all__ = ['ClosedLoop', 'FastBlock', 'clipped_mean', 'map_state']


class ClosedLoop:
    """The closed loop for one plant: matrices of both paths (built on first use)."""

    def __init__(self, spec: Physics, controller: Controller, cfg: SimulatorConfig) -> None:
        self.spec = spec
        sp = sample_plant(spec, substeps=cfg.substeps)
        self.sp = sp
        cp = sp.continuous
        ac, bc, cc, dc = controller.state_space()
        nx, nc = cp.a.shape[0], ac.shape[0]
        w = sp.whole
        nh = w + 1                                # register u[k-1] .. u[k-w-1]
        nz = nx + nh + nc
        self.nx, self.nh, self.nc, self.nz = nx, nh, nc, nz
        gain = spec.gain_ratio
        # z' = az z + be e + bff uff + bn n + gd dnl ; u = cu z + dc e + uff
        cu = np.zeros(nz)
        cu[nx + nh:] = cc
        az = np.zeros((nz, nz))
        be = np.zeros(nz)
        bff = np.zeros(nz)
        az[:nx, :nx] = sp.phi
        az[:nx, nx + w] += sp.g_old                 # u_old = u[k-w-1] = register[w]
        if w == 0:                                  # u_new = u[k]
            az[:nx] += np.outer(sp.g_new, cu)
            be[:nx] += sp.g_new * dc
            bff[:nx] += sp.g_new
        else:                                       # u_new = register[w-1]
            az[:nx, nx + w - 1] += sp.g_new
        az[nx] = cu                                 # register[0] <- u[k]
        be[nx] = dc
        bff[nx] = 1.0
        for i in range(1, nh):
            az[nx + i, nx + i - 1] = 1.0
        az[nx + nh:, nx + nh:] = ac
        be[nx + nh:] = bc
        bn = np.zeros(nz)
        bn[:nx] = gain * sp.g_d
        gd = np.zeros((nz, sp.substeps))
        gd[:nx] = sp.gamma_d
        cy = np.zeros(nz)
        cy[:nx] = cp.c
        self.az, self.be, self.bff, self.bn, self.gd, self.cy, self.cu = az, be, bff, bn, gd, cy, cu
        self.dc = float(dc)
        # Fast path: m = y + v + q -> e = r - cy z - v - q ; inputs w = [r, uff, n, v, q].
        self.a_cl = az - np.outer(be, cy)
        self.b_cl = np.stack([be, bff, bn, -be, -be], axis=1)
        self.cu_cl = cu - dc * cy
        self.du_cl = np.array([dc, 1.0, 0.0, -dc, -dc])
        poles = np.linalg.eigvals(self.a_cl)
        self.spectral_radius = float(np.max(np.abs(poles)))
        if self.spectral_radius >= 1:
            raise ConfigurationError(
                f'the closed loop is unstable on this plant (spectral radius '
                f'{self.spectral_radius:.6f}); plant parameters: {spec.parameters()}')
        self._fast: dict[tuple[int, int], FastBlock] = {}
        # Saturation. The amplifier current i(t) inside a sample follows from the lag alone
        # (d does not act on it): i(t) = coef(t) @ [i0, u_old, u_new]; rows for the start,
        # middle and end of each sub-step. Over a sub-step where |i| stays beyond the limit the
        # motor sees the constant limit current: the lag's own contribution to the mechanics
        # (sat_r @ [i_start, u_old, u_new], carried to the sample's end) is replaced by it,
        # exactly. A sub-step where i crosses the limit holds the clipped part at its midpoint.
        substeps = sp.substeps
        h = cfg.sample_period / substeps
        lag = spec.lag_time_constant

        def coef(t: float, *, closed: bool) -> tuple[float, float, float]:
            if lag > 0:
                if t <= sp.split:
                    e1 = math.exp(-t / lag)
                    return (e1, 1 - e1, 0.0)
                e1, e2 = math.exp(-sp.split / lag), math.exp(-(t - sp.split) / lag)
                return (e1 * e2, (1 - e1) * e2, 1 - e2)
            old = t <= sp.split if closed else t < sp.split
            return (0.0, 1.0, 0.0) if old else (0.0, 0.0, 1.0)

        self.sat_coef = np.array([[coef(j * h, closed=False) for j in range(substeps)],
                                  [coef((j + 0.5) * h, closed=False) for j in range(substeps)],
                                  [coef((j + 1) * h, closed=True) for j in range(substeps)]])
        self.sat_split = np.array([j * h < sp.split < (j + 1) * h for j in range(substeps)])
        self.sat_new = [j * h >= sp.split for j in range(substeps)]  # u_new drives sub-step j
        self.sat_h = h
        self.lag = lag
        mech = np.ones(nx)
        if cp.current_index is not None:
            mech[cp.current_index] = 0.0
        lag_col = (sp.sub_phi[:, cp.current_index] if cp.current_index is not None
                   else np.zeros(nx))
        sat_r = np.zeros((substeps, nz, 3))
        carry = np.eye(nx)                          # sub_phi^(substeps - 1 - j), j descending
        for j in range(substeps - 1, -1, -1):
            drives = np.stack([lag_col, sp.sub_g_old[j], sp.sub_g_new[j]], axis=1)
            sat_r[j, :nx] = carry @ (mech[:, None] * drives)
            carry = carry @ sp.sub_phi
        self.sat_r = sat_r
        # Whole sample beyond the limit (i0, u_old, u_new all beyond it on one side): the sum
        # of the sub-step corrections, as one matrix on [i0, u_old, u_new].
        pick = np.zeros((substeps, 3, 3))
        pick[:, 0, :] = self.sat_coef[0]
        pick[:, 1, 1] = 1.0
        pick[:, 2, 2] = 1.0
        self.sat_r_full = np.einsum('jnk,jkl->nl', sat_r, pick)
        self.gd_sum_limit = gd.sum(axis=1) * gain * spec.current_limit \
            if math.isfinite(spec.current_limit) else np.zeros(nz)
        self.limit = spec.current_limit
        self.gain = gain
        # Friction: the rigid-body velocity's row of the update and its gain from d.
        self.friction = spec.friction_current
        self.v_index = cp.velocity_index
        self.v_gain = float(sp.g_d[cp.velocity_index])
        self.gd_sum = gd.sum(axis=1)
        self.i_index = cp.current_index
        # Cogging: a current of the rigid body's angle and velocity at the sample's start,
        # held over the sample (Physics.cogging, written out for speed).
        self.p_index = cp.position_index
        self.cog = (spec.cogging_amplitude, 2 * math.pi / spec.cogging_period,
                    spec.cogging_phase, 0.5 * cfg.sample_period)
        # Encoder cyclic error: the reading of the shaft angle (Physics.reading).
        self.enc = (spec.encoder_error_amplitude, 2 * math.pi / spec.encoder_error_period,
                    spec.encoder_error_phase)
        # Proposed terms (Physics.term_current, Physics.reading): a current of the rigid
        # body's angle, velocity, acceleration (its velocity change over the previous sample,
        # carried from move to move in last_velocity) and the command, held over the sample.
        self.terms = dict(spec.terms)
        self.term_current = spec.current_terms
        self.term_reading = spec.reading_error and bool(spec.terms)
        self.last_velocity = 0.0

    def exact_move(self, z: NDArray[np.float64], r: NDArray[np.float64],
                   ff: NDArray[np.float64], n: NDArray[np.float64], v: NDArray[np.float64],
                   record: int, quantum: float) -> tuple[NDArray[np.float64],
                                                        NDArray[np.float64]]:
        """Sample-by-sample simulation of one move (quantiser in the loop, nonlinear effects);
        updates ``z`` in place."""  # noqa: D205, D209
        loop = self
        q = quantum
        length = r.shape[0]
        nz = loop.nz
        pre = (np.outer(loop.be, r) + np.outer(loop.bff, ff) + np.outer(loop.bn, n)).T.copy()
        # One product gives the free next state and both outputs: [az; cy; cu] @ z.
        big = np.vstack([loop.az, loop.cy, loop.cu])
        be_neg = -loop.be
        dc = loop.dc
        u_rec = np.empty(record)
        y_rec = np.empty(record)
        w = loop.sp.whole
        idx_old, idx_new = loop.nx + w, loop.nx + w - 1
        limit, friction = loop.limit, loop.friction
        saturation = math.isfinite(limit)
        cog_a, cog_k, cog_ph, half_t = loop.cog
        enc_a, enc_k, enc_ph = loop.enc
        p_i, v_i = loop.p_index, loop.v_index
        terms, t_current, t_reading = loop.terms, loop.term_current, loop.term_reading
        term_law = current_law(terms)
        v_last, period = loop.last_velocity, 2.0 * half_t
        sin = math.sin
        zk = z.copy()
        floor = math.floor
        for k in range(length):
            out = big @ zk
            y = float(out[nz])
            if enc_a or t_reading:
                shaft = y
                if enc_a:
                    y += enc_a * sin(enc_k * shaft + enc_ph)
                if t_reading:
                    y += float(term_reading(terms, shaft))
            meas = y + v[k]
            if q > 0:
                meas = floor(meas / q + 0.5) * q
            uk = float(out[nz + 1]) + dc * (r[k] - meas) + ff[k]
            if k < record:
                u_rec[k] = uk
                y_rec[k] = meas
            z_next = out[:nz]
            z_next += pre[k]
            z_next += be_neg * meas
            if saturation:
                u_old = float(zk[idx_old])
                u_new = uk if w == 0 else float(zk[idx_new])
                i0 = float(zk[loop.i_index]) if loop.i_index is not None else u_old
                if max(abs(i0), abs(u_old), abs(u_new)) > limit:
                    z_next += self._saturation(i0, u_old, u_new)
            if cog_a:
                half = cog_k * float(zk[v_i]) * half_t
                sinc = sin(half) / half if half else 1.0
                z_next += loop.gd_sum * (cog_a * sin(cog_k * float(zk[p_i]) + half + cog_ph)
                                         * sinc)
            if t_current:
                vk = float(zk[v_i])
                z_next += loop.gd_sum * float(term_law(float(zk[p_i]), vk, (vk - v_last) / period,
                                                       uk))
                v_last = vk
            if friction > 0:
                self._friction(zk, z_next)
            zk = z_next
        z[:] = zk
        loop.last_velocity = v_last
        return u_rec, y_rec

    def _saturation(self, i0: float, u_old: float, u_new: float) -> NDArray[np.float64]:
        """Correction of the next state for the amplifier's current limit over one sample."""
        loop = self
        limit, gain = loop.limit, loop.gain
        x = np.array([i0, u_old, u_new])
        if not loop.sat_split.any():
            if min(i0, u_old, u_new) > limit:
                return np.asarray(loop.gd_sum_limit - loop.sat_r_full @ x, dtype=np.float64)
            if max(i0, u_old, u_new) < -limit:
                return np.asarray(-loop.gd_sum_limit - loop.sat_r_full @ x, dtype=np.float64)
        start, mid, end = loop.sat_coef @ x                   # (substeps,) each
        above = (start > limit) & (mid > limit) & (end > limit) & ~loop.sat_split
        below = (start < -limit) & (mid < -limit) & (end < -limit) & ~loop.sat_split
        d = gain * (np.clip(mid, -limit, limit) - mid)        # crossing sub-steps: midpoint
        full = above | below
        d[above] = gain * limit
        d[below] = -gain * limit
        if loop.lag > 0:  # crossing sub-steps: the exact mean of the clipped part instead
            crossing = np.flatnonzero(~full & ~loop.sat_split & (
                (np.abs(start) > limit) | (np.abs(end) > limit)))
            for j in crossing:
                u_a = u_new if loop.sat_new[j] else u_old
                d[j] = -gain * clipped_mean(float(start[j]), u_a, limit, loop.lag, loop.sat_h)
        corr: NDArray[np.float64] = loop.gd @ d
        if full.any():
            drives = np.stack([start[full], np.full(int(full.sum()), u_old),
                               np.full(int(full.sum()), u_new)], axis=1)
            corr -= np.einsum('jnk,jk->n', loop.sat_r[full], drives)
        return corr

    def _friction(self, z: NDArray[np.float64], z_next: NDArray[np.float64]) -> None:
        """Add Coulomb friction (stick-slip, held over the sample) to ``z_next``.

        The rigid-body velocity at the sample's end is v_end = v_free + v_gain * d for a
        friction current -d held over the sample. Stuck (v = 0 exactly) while the friction
        needed to stay stuck is at most F; slipping with friction -F sign(v); a stop inside
        the sample ends stuck, a reversal splits the sample at the linearly interpolated zero.
        """
        loop = self
        f = loop.friction
        v0 = float(z[loop.v_index])
        v_free = float(z_next[loop.v_index])
        gain = loop.v_gain
        hold = -v_free / gain                      # friction current keeping v_end = 0
        stop = False
        if v0 == 0.0:
            if abs(hold) <= f:
                d, stop = hold, True
            else:
                d = -f if v_free > 0 else f
        else:
            sign = 1.0 if v0 > 0 else -1.0
            d = -f * sign
            v_end = v_free + gain * d
            if v_end * sign <= 0:
                if abs(hold) <= f:
                    d, stop = hold, True
                else:                              # reverses: friction flips at the zero
                    theta = v0 / (v0 - v_end)
                    d = -f * sign * (2 * theta - 1)
        z_next += loop.gd_sum * d
        if stop:
            z_next[loop.v_index] = 0.0

    def fast(self, record: int, total: int) -> FastBlock:
        """The fast path's block for moves of ``total`` samples, ``record`` of them recorded."""
        key = (record, total)
        if key not in self._fast:
            self._fast[key] = FastBlock(self, record, total)
        return self._fast[key]


class FastBlock:
    """Markov parameters and transition powers of the linear closed loop over one move."""

    def __init__(self, loop: ClosedLoop, record: int, total: int) -> None:
        a, b = loop.a_cl, loop.b_cl
        nz, ni = b.shape
        # A^k B (k < total) and [cy; cu] A^k (k < record) by doubling: one batched product
        # per power of two.
        akb = np.empty((total, nz, ni))
        akb[0] = b
        rows = np.empty((record, 2, nz))
        rows[0] = np.stack([loop.cy, loop.cu_cl])
        power = a
        filled = 1
        while filled < total:
            count = min(filled, total - filled)
            akb[filled:filled + count] = power @ akb[:count]
            if filled < record:
                rc = min(filled, record - filled)
                rows[filled:filled + rc] = rows[:rc] @ power
            filled += count
            power = power @ power
        # End state: sum_k A^(L-1-k) B w[k]  ->  (nz, ni * total) against w.reshape(ni * total)
        self.g = akb[::-1].transpose(1, 2, 0).reshape(nz, ni * total)
        self.o_y = rows[:, 0]                                  # (record, nz): cy A^k
        self.o_u = rows[:, 1]
        self.a_total = np.linalg.matrix_power(a, total)
        h_y = np.zeros((record, ni))
        h_u = np.zeros((record, ni))
        h_y[1:] = np.einsum('n,kni->ki', loop.cy, akb[:record - 1])
        h_u[1:] = np.einsum('n,kni->ki', loop.cu_cl, akb[:record - 1])
        h_u[0] = loop.du_cl
        self.nfft = 1 << (2 * record - 1).bit_length()
        self.hf_y = np.fft.rfft(h_y, self.nfft, axis=0)       # (nfft/2+1, ni)
        self.hf_u = np.fft.rfft(h_u, self.nfft, axis=0)
        self.record, self.total, self.ni = record, total, ni

    def run(self, z0: NDArray[np.float64], w: NDArray[np.float64]) -> tuple[
            NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Simulate M back-to-back moves from state z0 with inputs w (M, ni, total).

        Returns:
            (y (M, record), u (M, record), start states (M + 1, nz)).
        """
        m = w.shape[0]
        forced = w.reshape(m, -1) @ self.g.T                  # (M, nz)
        starts = np.empty((m + 1, z0.shape[0]))
        starts[0] = z0
        for i in range(m):
            starts[i + 1] = self.a_total @ starts[i] + forced[i]
        wf = np.fft.rfft(w[:, :, :self.record], self.nfft, axis=-1)   # (M, ni, F)
        y = np.fft.irfft(np.einsum('mif,fi->mf', wf, self.hf_y), self.nfft, axis=-1)
        u = np.fft.irfft(np.einsum('mif,fi->mf', wf, self.hf_u), self.nfft, axis=-1)
        y = y[:, :self.record] + starts[:m] @ self.o_y.T
        u = u[:, :self.record] + starts[:m] @ self.o_u.T
        return y, u, starts


def clipped_mean(i_start: float, u_a: float, limit: float, lag: float, h: float) -> float:
    """Mean over [0, h] of i - clip(i) for i(t) = u_a + (i_start - u_a) exp(-t / lag)."""
    amp = i_start - u_a
    total = 0.0
    for sign in (1.0, -1.0):                      # the part beyond +limit, then beyond -limit
        level = sign * limit
        # i(t) - level is monotone; the part of [0, h] where sign * (i - level) > 0:
        e_h = math.exp(-h / lag)
        beyond_start = sign * (i_start - level) > 0
        beyond_end = sign * (u_a + amp * e_h - level) > 0
        if not (beyond_start or beyond_end):
            continue
        if beyond_start and beyond_end:
            a, b = 0.0, h
        else:
            t_cross = lag * math.log(amp / (level - u_a))
            a, b = (0.0, t_cross) if beyond_start else (t_cross, h)
        # integral of i - level over [a, b]
        total += (u_a - level) * (b - a) + amp * lag * (math.exp(-a / lag) - math.exp(-b / lag))
    return total / h


def map_state(x: NDArray[np.float64], old: ContinuousPlant,
               new: ContinuousPlant) -> NDArray[np.float64]:
    """Carry the plant state over a change of its layout (new modes start at rest)."""
    if old.a.shape == new.a.shape and old.current_index == new.current_index:
        return x.copy()
    out = np.zeros(new.a.shape[0])
    if old.current_index is not None and new.current_index is not None:
        out[new.current_index] = x[old.current_index]
    o_off, n_off = old.position_index, new.position_index
    pairs = min((x.shape[0] - o_off) // 2, (out.shape[0] - n_off) // 2)
    out[n_off:n_off + 2 * pairs] = x[o_off:o_off + 2 * pairs]
    return out
