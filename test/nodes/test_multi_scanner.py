"""Several scanners on one DDS domain (issue 7, "Scale past one machine").

N = 4 galvo_driver / sysid / watchdog triples in namespaces /scanner_1 ... /scanner_4, all
started as separate processes on the same ROS_DOMAIN_ID. Each driver's simulated plant has its
own omega_1 (a step of omega_1 by a factor per scanner, set as a driver parameter), and every
driver numbers its moves from 0 with stamps from the same clock, so any cross-talk would show:
a window mixing scanners would identify an omega_1 between theirs, and moves reaching the
wrong sysid would be set aside as duplicate move_ids. Checked per namespace: every window's
omega_1 is its own plant's, no move set aside, and /diagnostics carries each scanner's own
'plant drift' (OK or ERROR as its plant deserves) and 'identification' status.
"""

from __future__ import annotations

import functools
import time
from typing import TYPE_CHECKING

from diagnostic_msgs.msg import DiagnosticArray
from galvo_sysid_msgs.msg import ModalParameters
from ros_graph import RESULTS_QOS, Graph, counters

from galvo_sysid.model import REFERENCE_MODEL

if TYPE_CHECKING:
    pass

OMEGA_1 = REFERENCE_MODEL.natural_frequencies[0]
# omega_1 factor of each scanner's plant, and the drift level its watchdog must report
SCANNERS = {'scanner_1': (1.0, 0), 'scanner_2': (0.97, 2), 'scanner_3': (1.002, 0),
            'scanner_4': (0.985, 2)}
WINDOW = 20


def _level_is(diags: dict[tuple[str, str], int], name: str, level: int) -> bool:
    return diags.get((name, 'plant drift')) == level



def test_four_scanners_in_namespaces_never_mix(graph: Graph) -> None:
    results: dict[str, list[ModalParameters]] = {name: [] for name in SCANNERS}
    diags: dict[tuple[str, str], int] = {}

    def on_diag(msg: DiagnosticArray) -> None:
        for s in msg.status:
            diags[(s.hardware_id, s.name.split(': ', 1)[-1])] = int.from_bytes(s.level,
                                                                                 'little')

    graph.node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 100)
    sysids = {}
    for name, (factor, _) in SCANNERS.items():
        graph.node.create_subscription(ModalParameters, f'/{name}/galvo/modal_parameters',
                                       results[name].append, RESULTS_QOS)
        remap = f'__ns:=/{name}'
        sysids[name] = graph.start('sysid', f'{name}_sysid', '-r', remap,
                                   '-p', f'window_size:={WINDOW}', '-p', 'fit_processes:=0',
                                   '-p', 'stats_period:=1.0')
        graph.start('watchdog', f'{name}_watchdog', '-r', remap, '-p', 'publish_rate:=4.0')
        graph.start('galvo_driver', f'{name}_driver', '-r', remap, '-p', 'angles:=[0.9]',
                    '-p', f'moves_per_angle:={2 * WINDOW}', '-p', 'rate_factor:=0.25',
                    '-p', 'step.parameter:=omega_1', '-p', f'step.factor:={factor}',
                    '-p', 'step.at_move:=0', '-p', f'seed:={len(sysids)}')

    def enough() -> bool:
        return all(len(r) >= 3 for r in results.values()) and all(
            (name, part) in diags for name in SCANNERS
            for part in ('plant drift', 'identification'))
    start = time.monotonic()
    graph.spin_until(enough, 120, 'three windows and diagnostics from every scanner')
    took = time.monotonic() - start

    for name, (factor, level) in SCANNERS.items():
        for m in results[name]:
            assert m.moves == WINDOW
            ratio = m.natural_frequencies[0] / OMEGA_1
            assert abs(ratio - factor) < 0.0008, (name, ratio, factor)
        graph.spin_until(functools.partial(_level_is, diags, name, level), 10,
                         f'{name} drift level {level}')
        c = counters(sysids[name].text())
        assert c, name
        assert c[-1]['moves_rejected'] == 0, (name, c[-1])
    assert {h for h, _ in diags} >= set(SCANNERS)
    assert 'Traceback' not in graph.logs(100_000)
    print(f'4 scanners: 12 processes, three windows each after {took:.1f} s')
