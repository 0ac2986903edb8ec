"""The sysid node fed a coil current measured when the encoder is read, over real DDS.

Scanner 1 of the independent simulator (``test/independent_scanner.py``; 22 us, one mode at
3.45 kHz, amplifier lag 0.78 T) publishes its measured current; the node, given
``current:=measured`` and the lag, makes each window's current held before the fit and
identifies the mode within its std of the truth, under the truth's model of the held current
(no computation delay, the lag); its diagnostics say which current it takes.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from galvo_sysid_msgs.msg import ModalParameters, MoveSamples
from independent_scanner import random_scanner, simulate
from ros_graph import MOVES_QOS, RESULTS_QOS, Graph, wait_matched

from galvo_sysid.interfaces.messages import fill, fill_header, move_samples_fields
from galvo_sysid.model import InputDynamics, ModalModel, PlantModel
from galvo_sysid.model.files import save_model

if TYPE_CHECKING:
    from pathlib import Path


def test_a_measured_current_is_identified_live(graph: Graph, tmp_path: Path) -> None:
    s = random_scanner(1)
    t = s.sample_period
    data = simulate(s, angles=[0.3], moves_per_angle=200, seed=3, current='measured')
    model = save_model(PlantModel(
        modal=ModalModel(k0=s.k0, residues=s.residues, natural_frequencies=s.omegas,
                         damping_ratios=s.zetas),
        dynamics=InputDynamics(computation_delay=0, lag_time_constant=s.lag),
        sample_period=t, record_length=s.record - 1), tmp_path / 'held.yaml')
    ns = '/measured_live'
    results: list[ModalParameters] = []
    statuses: list[DiagnosticArray] = []
    graph.node.create_subscription(ModalParameters, f'{ns}/galvo/modal_parameters',
                                   results.append, RESULTS_QOS)
    graph.node.create_subscription(DiagnosticArray, '/diagnostics', statuses.append, 10)
    pubs = {k: graph.node.create_publisher(MoveSamples, f'{ns}/galvo/{k}', MOVES_QOS)
            for k in ('current', 'encoder')}
    graph.start('sysid', 'sysid', '-r', f'__ns:={ns}', '-p', f'model:={model}',
                '-p', 'current:=measured', '-p', f'measured_current_lag:={s.lag!r}',
                '-p', 'fit_processes:=0', '-p', 'diagnostics_period:=0.5')
    wait_matched(graph, pubs.values())
    span = (s.record + s.dwell) * t
    for i, angle in enumerate(data['target_angle']):
        for k in ('current', 'encoder'):
            msg = fill(MoveSamples(), move_samples_fields(
                move_id=i, target_angle=float(angle), sample_period=t, data=data[k][i]))
            fill_header(msg, stamp=100.0 + i * span)
            pubs[k].publish(msg)
        if i % 20 == 19:
            graph.spin_for(0.02)
    graph.spin_until(lambda: len(results) >= 2, 60, 'both windows identified')
    graph.spin_until(lambda: any(v.key == 'current' for a in statuses for st in a.status
                                 for v in st.values), 10, 'a diagnostic of the node')
    assert sorted(m.target_angle for m in results) == [-0.3, 0.3]
    for m in results:
        assert m.status == 0, m.status_message
        assert m.moves == 100
        z = [(m.k0 - s.k0) / m.k0_std,
             (m.residues[0] - s.residues[0]) / m.residues_std[0],
             (m.natural_frequencies[0] - s.omegas[0]) / m.natural_frequencies_std[0],
             (m.damping_ratios[0] - s.zetas[0]) / m.damping_ratios_std[0]]
        assert max(abs(v) for v in z) < 4.5, z
        # the held current's delay is the lag alone (the measured one, as it came: none, and
        # the damping 5 std off)
        assert m.input_delay / t == pytest.approx(s.lag / t, abs=0.1)
    said = {v.value for a in statuses for st in a.status for v in st.values if v.key == 'current'}
    assert said == {f'measured, made held with an amplifier lag of {s.lag:.6g} s'}
