"""The workflow's open-loop plant reproduces the simulator and python-control's sampling."""

from __future__ import annotations

import numpy as np
from discrepancy_cases import CASES, PAIRS, hidden_effects, measured

from galvo_sysid.discrepancy import PlantSimulator
from galvo_sysid.model import PAPER_MODEL, TAU


def test_own_physics_reproduces_the_simulator_from_rest():
    """Noise-free, the first move starts at rest: the workflow's own simulation of the true
    model matches the simulator's encoder to rounding (saturation: to its sub-steps)."""
    for effect, truth, _ in [*CASES[1:PAIRS:2], *CASES[PAIRS:]]:
        if 'phase' in truth:    # at rest at 0 deg: no cogging torque, no reading error there
            truth = {**truth, 'phase': 0.0}
        moves = measured(hidden_effects((effect, truth)), seed=0, moves_per_angle=2, noise=False)
        model = PAPER_MODEL.with_effect(effect, truth)
        sim = PlantSimulator(model.physics(), sample_period=TAU, length=moves.samples)
        y = sim.simulate(moves.current[0], moves.encoder[0, 0])
        tol = 3e-5 if effect == 'current_saturation' else 1e-10   # saturation: sub-steps
        assert np.max(np.abs(y - moves.encoder[0])) < tol, effect
        nominal = PlantSimulator(PAPER_MODEL.physics(), sample_period=TAU,
                                 length=moves.samples).simulate(moves.current[0], 0.0)
        assert np.max(np.abs(nominal - moves.encoder[0])) > 100 * tol, effect


def test_both_plants_match_python_control_sampling():
    """The workflow's plant and the simulator share the model's ZOH code; both are checked
    against python-control's own zero-order hold of the same transfer function (the paper
    model behind one sample of computation delay and the 0.6 tau lag)."""
    import control

    from galvo_sysid.model.sampling import sample_plant

    m = PAPER_MODEL.modal
    # a parallel connection of second-order state spaces (a transfer function of the whole
    # ninth-order plant would be numerically poor), behind the lag
    mech = control.ss(control.tf([m.k0], [1.0, 0.0, 0.0]))
    for k, w, z in zip(m.residues, m.natural_frequencies, m.damping_ratios, strict=True):
        mech = control.parallel(mech, control.ss(control.tf([k], [1.0, 2 * z * w, w * w])))
    lag = PAPER_MODEL.dynamics.lag_time_constant
    plant = control.c2d(control.series(control.ss(control.tf([1.0], [lag, 1.0])), mech), TAU,
                        method='zoh')
    u = np.random.default_rng(4).normal(size=300)
    u[:5] = 0.0
    delayed = np.concatenate([[0.0], u[:-1]])  # one sample of computation delay
    _, y_ref = control.forced_response(plant, T=np.arange(300) * TAU, U=delayed)
    y_disc = PlantSimulator(PAPER_MODEL.physics(), sample_period=TAU, length=300).simulate(u, 0.0)
    sp = sample_plant(PAPER_MODEL.physics())
    x = np.zeros(sp.phi.shape[0])
    y_sim = np.empty(300)
    for k in range(300):
        y_sim[k] = sp.continuous.c @ x
        x = sp.phi @ x + sp.g_old * delayed[k - 1] * (k > 0) + sp.g_new * delayed[k]
    scale = float(np.max(np.abs(y_ref)))
    np.testing.assert_allclose(y_disc, y_ref, atol=1e-7 * scale)
    np.testing.assert_allclose(y_sim, y_ref, atol=1e-7 * scale)
