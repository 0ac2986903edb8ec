"""Bags straight from the simulator (``galvo-sysid simulate``), no ROS graph involved.

:func:`simulate_bag` runs :class:`~galvo_sysid.sim.simulator.GalvoSimulator` over a schedule of
moves and writes what the galvo_driver node would publish: per move one ``MoveSamples`` on
``/galvo/current`` and one on ``/galvo/encoder`` with the same ``move_id``, header stamp = the
simulated time of the move's first sample; the bag's log time is that stamp too.

Plant changes and effects are given as short texts (the command line's syntax):

- drift ``PARAM=RATE/UNIT[@START]``: relative change per second (``/s``) or per move
  (``/move``), from ``START`` on (same unit; default 0). ``omega_1=-2e-5/move``: omega_1
  falls 0.002 % per move, 0.2 % per 100 moves.
- step ``PARAM=FACTOR@WHEN``: the parameter is multiplied by ``FACTOR`` from move ``WHEN`` on
  (``@1.5s``: from 1.5 s of simulated time). ``k0=0.9@400``.
- effect ``NAME:KEY=VALUE[,KEY=VALUE...]``: a physical effect of
  :data:`~galvo_sysid.model.effects.EFFECT_NAMES`, e.g. ``coulomb_friction:friction_current=0.05``,
  ``unmodeled_resonance:natural_frequency=3e4,damping_ratio=0.01,residue=1e5``.

The moves are written as they are simulated, :data:`CHUNK` moves at a time (memory does not
grow with the schedule), into a bag that appears under its name only when complete
(:func:`~galvo_sysid.field.bags.atomic.atomic_bag`): a failed or interrupted run leaves
nothing that blocks the next one. The schedule is bounded like the ``galvo_driver``'s
(``moves_per_angle`` and ``seed`` of :data:`~galvo_sysid.monitor.parameters.DRIVER_PARAMETERS`),
and a bag that would not fit on its disk is refused before the first move.
"""

from __future__ import annotations

import math
import re
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.bags import CURRENT_TOPIC, ENCODER_TOPIC, BagWriter, stamp_to_ns
from galvo_sysid.field.bags.atomic import atomic_bag
from galvo_sysid.interfaces.topics import MOVE_SAMPLES
from galvo_sysid.model.files import model_label

if TYPE_CHECKING:
    import os
    from collections.abc import Iterable, Iterator, Sequence

    from numpy.typing import ArrayLike

    from galvo_sysid.model.changes import Drift, StepChange
    from galvo_sysid.sim.config import Move, SimulatorConfig
    from galvo_sysid.sim.simulator import GalvoSimulator

__all__ = [
    'CHUNK',
    'SimulationSummary',
    'check_space',
    'driver_qos',
    'parse_drift',
    'parse_step',
    'schedule_limits',
    'simulate_bag',
    'write_move',
    'write_moves',
]

CHUNK = 4096
"""Moves simulated per call of the simulator (a multiple of its batch of 64), then written."""

_COMPRESSED = 0.5
"""The smallest share of the raw sample bytes a bag takes on disk (zstd on noisy doubles
keeps about 60 %): the estimate that decides whether a bag fits."""


def schedule_limits() -> dict[str, tuple[int, int]]:
    """The ranges of ``moves_per_angle`` and ``seed``: the ``galvo_driver``'s (one source)."""
    from galvo_sysid.monitor.parameters import DRIVER_PARAMETERS

    return {s.name: (int(s.low or 0), int(s.high or 0)) for s in DRIVER_PARAMETERS
            if s.name in {'moves_per_angle', 'seed'}}


def driver_qos() -> dict[str, Any]:
    """The QoS ``galvo_driver`` offers on the move topics with its default parameters
    (``qos_depth``, ``qos_reliability``; volatile): what a simulated bag stores as offered,
    as ``ros2 bag record`` of the live driver would (keyword arguments of
    :meth:`~galvo_sysid.field.bags.BagWriter.add_topic`)."""  # noqa: D205, D209
    from galvo_sysid.monitor.parameters import defaults

    values = defaults('galvo_driver')
    return {'reliable': values['qos_reliability'] == 'reliable', 'transient_local': False,
            'depth': values['qos_depth']}


_NUMBER = r'[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?'
_DRIFT = re.compile(rf'^\s*(\w+)\s*=\s*({_NUMBER})\s*/\s*(s|second|move)\s*'
                    rf'(?:@\s*({_NUMBER})\s*(s|move)?)?\s*$')
_STEP = re.compile(rf'^\s*(\w+)\s*=\s*({_NUMBER})\s*@\s*({_NUMBER})\s*(s|move)?\s*$')


def parse_drift(text: str) -> Drift:
    """``PARAM=RATE/UNIT[@START]`` -> :class:`~galvo_sysid.model.changes.Drift` (relative rate).

    Raises:
        ConfigurationError: Bad syntax or unknown parameter.
    """
    from galvo_sysid.model.changes import Drift

    m = _DRIFT.match(text)
    if not m:
        msg = (f'bad drift {text!r}: expected PARAM=RATE/UNIT[@START], e.g. '
               f'omega_1=-2e-5/move or k0=-0.001/s@2')
        raise ConfigurationError(msg)
    name, rate, unit, start, start_unit = m.groups()
    unit = 'second' if unit in {'s', 'second'} else 'move'
    if start_unit and {'s': 'second'}.get(start_unit, start_unit) != unit:
        msg = f'bad drift {text!r}: START must be in the unit of the rate ({unit})'
        raise ConfigurationError(msg)
    return Drift(parameter=name, rate=float(rate), unit=unit,
                 start=float(start) if start else 0.0, relative=True)


def parse_step(text: str) -> StepChange:
    """``PARAM=FACTOR@WHEN[s]`` -> :class:`~galvo_sysid.model.changes.StepChange` (a factor).

    Raises:
        ConfigurationError: Bad syntax or unknown parameter.
    """
    from galvo_sysid.model.changes import StepChange

    m = _STEP.match(text)
    if not m:
        msg = f'bad step {text!r}: expected PARAM=FACTOR@MOVE or PARAM=FACTOR@SECONDSs, ' \
              f'e.g. k0=0.9@400'
        raise ConfigurationError(msg)
    name, factor, at, unit = m.groups()
    return StepChange(parameter=name, value=float(factor), at=float(at),
                      unit='second' if unit == 's' else 'move', relative=True)


@dataclass(frozen=True)
class SimulationSummary:
    """What :func:`simulate_bag` wrote.

    Attributes:
        path: The bag.
        moves: Moves written.
        angles: The schedule's angles [deg].
        scanner_time: Simulated time covered [s].
        seconds: Wall-clock time taken [s].
        size: Bytes on disk.
        changes: Human-readable plant changes and effects.
        sample_period: The scanner's sample period [s].
        record_length: Recorded samples per move.
        dwell_length: Samples between a record's end and the next move.
        model: The plant-model file simulated ('': the packaged paper model).
    """

    path: Path
    moves: int
    angles: tuple[float, ...]
    scanner_time: float
    seconds: float
    size: int
    changes: tuple[str, ...] = field(default=())
    sample_period: float = math.nan
    record_length: int = 0
    dwell_length: int = 0
    model: str = ''

    def __str__(self) -> str:
        extra = f'; {", ".join(self.changes)}' if self.changes else ''
        return (f'simulate: {self.moves} moves over {len(self.angles)} angle(s), '
                f'{self.scanner_time:.2f} s of scanner time; scanner {model_label(self.model)}: '
                f'sample period {self.sample_period * 1e6:.4g} us, records of '
                f'{self.record_length} samples + {self.dwell_length} dwell{extra} -> '
                f'{self.path} ({self.size / 1e6:.2f} MB) in {self.seconds:.2f} s')


def write_moves(bag: BagWriter, moves: Iterable[Move], *, frame_id: str = '') -> int:
    """Write simulator moves as the driver node publishes them; return how many.

    The bag must have :data:`~galvo_sysid.field.bags.CURRENT_TOPIC` and
    :data:`~galvo_sysid.field.bags.ENCODER_TOPIC` added as ``MoveSamples``.
    """
    count = 0
    for move in moves:
        write_move(bag, move_id=move.move_id, target_angle=move.target_angle,
                   stamp=move.stamp, sample_period=move.sample_period, current=move.current,
                   encoder=move.encoder, frame_id=frame_id)
        count += 1
    return count


def write_move(bag: BagWriter, *, move_id: int, target_angle: float, stamp: float,
               sample_period: float, current: ArrayLike, encoder: ArrayLike,
               frame_id: str = '') -> None:
    """Write one move as the driver node publishes it (what :func:`write_moves` writes).

    One ``MoveSamples`` on :data:`~galvo_sysid.field.bags.CURRENT_TOPIC`, then one on
    :data:`~galvo_sysid.field.bags.ENCODER_TOPIC`, with the same ``move_id``; header stamp
    and log time ``stamp`` [s]. The bag must have both topics added as ``MoveSamples``.
    """
    ns = stamp_to_ns(stamp)
    for topic, data in ((CURRENT_TOPIC, current), (ENCODER_TOPIC, encoder)):
        msg = bag.move_samples(stamp=stamp, move_id=move_id, target_angle=target_angle,
                               sample_period=sample_period, data=data, frame_id=frame_id)
        bag.write(topic, ns, msg)


def simulate_bag(out: str | os.PathLike[str], *, angles: Sequence[float],
                 moves_per_angle: int = 200, seed: int = 0, storage: str = 'mcap',
                 drift: Sequence[str] = (), steps: Sequence[str] = (),
                 effects: Sequence[str] = (), config: SimulatorConfig | None = None,
                 frame_id: str = '', model_path: str = '') -> SimulationSummary:
    """Simulate a schedule of moves and write them into a new bag.

    Args:
        out: Bag directory to create.
        angles: Target angles [deg]; each gets ``moves_per_angle`` moves alternating
            +angle and -angle.
        moves_per_angle: Moves per angle (even; the range of the ``galvo_driver``'s
            ``moves_per_angle``, :func:`schedule_limits`).
        seed: Noise seed (the range of the ``galvo_driver``'s ``seed``).
        storage: ``'mcap'`` or ``'sqlite3'``.
        drift: Drifts, ``PARAM=RATE/UNIT[@START]`` (see the module docs).
        steps: Step changes, ``PARAM=FACTOR@WHEN``.
        effects: Physical effects, ``NAME:KEY=VALUE,...``.
        config: Base simulator configuration (default: the paper's scanner); its plant model
            sets the sample period, record and dwell lengths unless the config overrides them.
        frame_id: Header frame id of the messages.
        model_path: The file of the config's plant model, for the summary ('': the packaged
            paper model).

    Raises:
        ConfigurationError: Bad schedule, seed, change or effect; the bag would not fit on
            its disk.
        BagExistsError: ``out`` exists.
        OSError: Writing failed (e.g. the disk is full); nothing is left under ``out``.
    """
    from galvo_sysid.model.effects import parse_effect
    from galvo_sysid.sim.config import SimulatorConfig
    from galvo_sysid.sim.simulator import GalvoSimulator

    if not angles:
        msg = 'no angles given'
        raise ConfigurationError(msg)
    limits = schedule_limits()
    low, high = limits['moves_per_angle']
    if isinstance(moves_per_angle, bool) or not isinstance(moves_per_angle, int) or not (
            low <= moves_per_angle <= high) or moves_per_angle % 2:  # forward and back
        msg = (f'moves-per-angle must be an even number within {low}..{high}, got '
               f'{moves_per_angle!r}')
        raise ConfigurationError(msg)
    low, high = limits['seed']
    if isinstance(seed, bool) or not isinstance(seed, int) or not low <= seed <= high:
        msg = f'seed must be a whole number within {low}..{high}, got {seed!r}'
        raise ConfigurationError(msg)
    base = config or SimulatorConfig()
    plant = base.plant.with_effects([parse_effect(text) for text in effects])
    cfg = replace(base, plant=plant,
                  drifts=(*base.drifts, *(parse_drift(d) for d in drift)),
                  steps=(*base.steps, *(parse_step(s) for s in steps)))
    start = time.perf_counter()
    sim = GalvoSimulator(config=cfg, seed=seed)
    sim.check_angles(angles)
    path = Path(out)
    check_space(path, moves=len(angles) * moves_per_angle, samples=sim.config.record)
    with atomic_bag(path) as partial, BagWriter(partial, storage=storage) as bag:
        for topic in (CURRENT_TOPIC, ENCODER_TOPIC):
            bag.add_topic(topic, MOVE_SAMPLES, **driver_qos())
        count = write_moves(bag, _schedule(sim, angles, moves_per_angle), frame_id=frame_id)
    size = sum(p.stat().st_size for p in path.rglob('*') if p.is_file())
    changes = (*(f'drift {d}' for d in drift), *(f'step {s}' for s in steps),
               *(f'effect {e}' for e in effects))
    return SimulationSummary(path=path, moves=count, angles=tuple(angles),
                             scanner_time=sim.time, seconds=time.perf_counter() - start,
                             size=size, changes=changes, sample_period=sim.config.sample_period,
                             record_length=sim.config.record, dwell_length=sim.config.dwell,
                             model=model_path)


def _schedule(sim: GalvoSimulator, angles: Sequence[float],
              moves_per_angle: int) -> Iterator[Move]:
    """The moves of the schedule, simulated :data:`CHUNK` at a time as they are taken.

    The same moves as ``sim.moves(angles=angles, moves_per_angle=moves_per_angle)`` (bit for
    bit within an angle; where one angle ends and the next starts, the simulator's batches no
    longer straddle the two, which changes the current by parts in 1e15), without its list of
    every target of the schedule.
    """
    for angle in angles:
        left = moves_per_angle
        while left:
            n = min(CHUNK, left)  # even: CHUNK and moves_per_angle are
            yield from sim.moves(angles=[angle], moves_per_angle=n)
            left -= n


def check_space(path: Path, *, moves: int, samples: int) -> None:
    """Refuse a bag that cannot fit on the disk it goes to (before the first move).

    Raises:
        ConfigurationError: Even compressed, the samples need more than the free space.
    """
    need = _COMPRESSED * moves * 2 * samples * 8  # current and encoder, float64
    where = next((p for p in (path, *path.parents) if p.exists()), Path('.'))
    try:
        free = shutil.disk_usage(where).free
    except OSError:
        return  # unknown: the write itself will say
    if need > free:
        msg = (f'the bag would take about {need / 1e9:.3g} GB ({moves * samples:,} samples '
               f'of current and of encoder), more than the {free / 1e9:.3g} GB free on '
               f'{where}')
        raise ConfigurationError(msg)
