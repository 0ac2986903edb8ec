"""Offline identification of a bag: what ``galvo-sysid identify`` runs (no ROS graph).

The moves of the bag go through exactly the objects the live nodes use, in the same order:
each ``MoveSamples`` message becomes a :class:`~galvo_sysid.monitor.moves.MoveHalf`
(:mod:`galvo_sysid.interfaces.messages`), :class:`~galvo_sysid.monitor.pairing.MoveWindower`
pairs them and cuts windows of ``window_size`` moves per signed target angle,
:func:`~galvo_sysid.ident.identify.identify_window` fits each window and
:class:`~galvo_sysid.monitor.drift.DriftMonitor` judges it. At the end of the bag, every
unfinished window holding at least ``min_partial`` moves (default: half a window) is
identified too and marked partial. Moves that cannot be used are listed with the reason; the
rest is used.

The pooled estimate (the bag's plant, from all windows; the nodes have no such thing) is, for
the refined method, :func:`~galvo_sysid.ident.identify.identify_joint`: one fit of the modal model
to the identified windows at once, started from
:func:`~galvo_sysid.ident.pool.pool_results` (the inverse-variance combination of the windows'
results), several times sharper on the weakly excited third mode. If the joint fit fails,
the inverse-variance combination is reported instead, with the reason. For the paper
methods the pooled estimate is the inverse-variance combination.

One plant model (a model file, default the paper's scanner) is used throughout: the windower
sets aside moves of another sample period, every window and the joint fit are identified with
it, and (unless another monitor is given) the drift is judged against it. Windows whose data
do not match it (:class:`~galvo_sysid.errors.ModelMismatchError`) are listed with the reason,
and the result says plainly that the data do not match the model
(:attr:`BagIdentification.model_mismatch`).
"""

from __future__ import annotations

import collections
import functools
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError, GalvoSysidError, InvalidDataError, one_line
from galvo_sysid.field.bags import BagInfo, BagReader, SetAside
from galvo_sysid.ident.identify import METHODS
from galvo_sysid.jsonsafe import finite_or_none
from galvo_sysid.model import model_label
from galvo_sysid.monitor.parameters import WINDOWER_PARAMETERS, defaults

if TYPE_CHECKING:
    import os
    from collections.abc import Callable

    from galvo_sysid.ident.result import IdentificationResult
    from galvo_sysid.model import ModalModel, PlantModel
    from galvo_sysid.monitor.drift import DriftMonitor
    from galvo_sysid.monitor.moves import Window
    from galvo_sysid.monitor.parameters import ParamSpec
    from galvo_sysid.monitor.rejections import Rejection
    from galvo_sysid.monitor.scheduler import FitOutcome
    from galvo_sysid.monitor.verdict import DriftVerdict

__all__ = [
    'JOINT_WINDOWS',
    'POOLINGS',
    'BagIdentification',
    'MismatchedWindow',
    'WindowResult',
    'identify_bag',
    'job_limit',
    'load_node_parameters',
    'rejection_to_dict',
]

_SYSID = defaults('sysid')
"""The sysid node's parameter defaults: :func:`identify_bag`'s defaults (one source)."""

POOLINGS = ('joint', 'inverse-variance')
"""Pooled estimates: one joint fit to the windows (refined method only), or the
inverse-variance combination of the windows' results."""

JOINT_WINDOWS = 64
"""Windows held for the joint fit at most (about 0.8 MB each for 100 moves of 512 samples)."""


JOB_BYTES = 200_000_000
"""Memory set aside per fit process when :func:`job_limit` caps the processes [bytes] (a
forked child fitting windows of 100 moves of 512 samples peaks near 60 MB; the rest is
margin for longer records and the parent's own share)."""


def job_limit() -> tuple[int, str]:
    """The most fit processes worth starting here, and why (``'2 CPU(s)'``, ...).

    The CPUs this process may run on (more processes only take turns), and the memory
    available (``MemAvailable`` of ``/proc/meminfo``, where there is one) over
    :data:`JOB_BYTES`: ``identify --jobs 40`` must not start 41 processes on two cores.
    """
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cpus = os.cpu_count() or 1
    limit, why = max(1, cpus), f'{max(1, cpus)} CPU(s)'
    available = _available_memory()
    if available is not None and available // JOB_BYTES < limit:
        limit = max(1, available // JOB_BYTES)
        why = f'{available / 1e9:.1f} GB of memory available'
    return limit, why


def _available_memory() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` [bytes], None where unknown."""
    try:
        with open('/proc/meminfo', encoding='ascii') as f:
            for line in f:
                if line.startswith('MemAvailable:'):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


_ROS_PARAMETERS = frozenset({'use_sim_time', 'start_type_description_service'})
"""Parameters every ROS 2 node has (not galvo_sysid's; a parameter file may set them)."""

_MAX_NESTING = 8
"""Deepest nesting of parameter names (``a.b.c...``) read from a parameter file."""


def load_node_parameters(path: str | os.PathLike[str], node: str) -> dict[str, Any]:
    """Read a ROS 2 parameter file (``--params-file``) for ``node``; nested names joined by '.'.

    Sections apply as ROS applies them: ``/**`` first, then sections naming the node (with or
    without namespace, e.g. ``sysid`` or ``/scanner_1/sysid``), later ones winning. The file is
    read by :func:`galvo_sysid.schema.load_yaml` (numbers as ROS reads them, no aliases) and
    checked as strictly as the node would take it: a node's section holds ``ros__parameters``
    only; each value has its parameter's declared type (:mod:`galvo_sysid.monitor.parameters`:
    ``10.7`` or ``"abc"`` is no ``window_size``, ``2`` no ``pair_timeout``: ROS refuses an
    integer for a floating-point parameter, write ``2.0``) and lies in its range; a name the
    node does not declare is refused, except, in a ``/**`` section, another galvo node's
    parameters and ROS's own (``use_sim_time``, ``qos_overrides...``). The watchdog's
    tolerances of modes beyond the declared three (``tolerances.k4``, ...) are read too.

    Returns:
        The node's parameters given in the file, by name, as written.

    Raises:
        ConfigurationError: Unreadable file, no section for the node, or a bad section, name
            or value (one line naming the file and the parameter).
    """
    from galvo_sysid.monitor.parameters import NODE_PARAMETERS
    from galvo_sysid.schema import load_yaml

    if node not in NODE_PARAMETERS:
        msg = f'unknown node {node!r}; known: {", ".join(NODE_PARAMETERS)}'
        raise ConfigurationError(msg)
    try:
        doc = load_yaml(path, what='parameter file')
    except InvalidDataError as err:  # missing, not a regular file, not text
        raise ConfigurationError(one_line(err)) from None
    except ConfigurationError as err:  # not valid YAML, an alias, too large
        raise ConfigurationError(f'cannot read parameter file {one_line(err)}') from None
    if not isinstance(doc, Mapping):
        msg = f'parameter file {path} is not a mapping of node names'
        raise ConfigurationError(msg)
    wildcard = [(str(k), v) for k, v in doc.items() if str(k) in {'/**', '**'}]
    named = [(str(k), v) for k, v in doc.items() if str(k).rstrip('/').split('/')[-1] == node]
    if not wildcard and not named:
        msg = f'parameter file {path} has no section for node {node!r} (nor /**)'
        raise ConfigurationError(msg)
    others = {s.name for name, specs in NODE_PARAMETERS.items() if name != node
              for s in specs}
    values: dict[str, Any] = {}
    for key, section in (*wildcard, *named):
        where = f'parameter file {path}: {key}'
        if not isinstance(section, Mapping) or set(section) - {'ros__parameters'}:
            msg = f'{where} must hold ros__parameters only'
            raise ConfigurationError(msg)
        params = section.get('ros__parameters')
        if params is None:
            continue
        for name, value in _flatten(params, where=f'{where}: ros__parameters').items():
            spec = _parameter_spec(node, name)
            if spec is None and node == 'watchdog' and name.startswith('reference.'):
                values[name] = value  # of older versions: reference_from_parameters says so
                continue
            if spec is None:
                if name in _ROS_PARAMETERS or name.startswith('qos_overrides.') or (
                        key in {'/**', '**'} and name in others):
                    continue  # ROS's own, or another node's in a section for all nodes
                msg = f'{where}: {node} has no parameter {_short(repr(name))} (a typo?)'
                raise ConfigurationError(msg)
            why = _parameter_type_error(spec, value) or spec.check(value)
            if why is not None:
                raise ConfigurationError(f'{where}: {_short(why)}')
            values[name] = value
    return values


def _flatten(tree: Any, *, where: str, prefix: str = '', depth: int = 0) -> dict[str, Any]:
    """A parameter file's nested mapping as ``{'a.b': value}`` (keys must be text)."""
    if not isinstance(tree, Mapping):
        msg = f'{where} must be a mapping of parameter names, got {type(tree).__name__}'
        raise ConfigurationError(msg)
    if depth > _MAX_NESTING:
        msg = f'{where}: parameter names nested deeper than {_MAX_NESTING}'
        raise ConfigurationError(msg)
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if not isinstance(key, str):
            msg = f'{where}: parameter name {_short(repr(key))} is not text'
            raise ConfigurationError(msg)
        name = f'{prefix}{key}'
        if isinstance(value, Mapping):
            out.update(_flatten(value, where=where, prefix=f'{name}.', depth=depth + 1))
        else:
            out[name] = value
    return out


def _parameter_spec(node: str, name: str) -> ParamSpec | None:
    """The declared parameter ``name`` of ``node`` (the watchdog's tolerances of any mode of a
    model: up to :data:`~galvo_sysid.model.plant.MAX_MODES`), or None."""  # noqa: D205, D209
    from galvo_sysid.model.plant import MAX_MODES
    from galvo_sysid.monitor.parameters import NODE_PARAMETERS, tolerance_specs
    from galvo_sysid.monitor.tolerances import split_parameter_name

    for spec in NODE_PARAMETERS[node]:
        if spec.name == name:
            return spec
    if node == 'watchdog' and name.startswith('tolerances.'):
        split = split_parameter_name(name.split('.', 1)[1])
        if split is not None and 1 <= split[1] <= MAX_MODES:
            found = [s for s in tolerance_specs(split[1], first_mode=split[1]) if s.name == name]
            return found[0] if found else None
    return None


def _parameter_type_error(spec: ParamSpec, value: Any) -> str | None:
    """Why ``value`` does not have the type ROS gives ``spec`` (its default's), or None."""
    default = spec.default

    def kind(v: Any, *, article: bool = True) -> str:
        text = {bool: 'a boolean', int: 'an integer', float: 'a floating-point number',
                str: 'text', list: 'a list', type(None): 'null'}.get(type(v), type(v).__name__)
        return text if article else text.split(' ', 1)[-1]

    def number(v: Any) -> bool:
        return isinstance(v, int | float) and not isinstance(v, bool)

    if default is None:  # an optional number: dynamically typed
        ok = value is None or number(value)
        need = 'a number (or null: not set)'
    elif isinstance(default, list):
        item = type(default[0]) if default else float
        ok = isinstance(value, list) and all(type(v) is item for v in value)
        need = f'a list of {kind(item(), article=False)}s'
    else:
        ok = type(value) is type(default)
        need = kind(default)
        if isinstance(default, float) and type(value) is int:
            need += f' (ROS refuses an integer here: write {value}.0)'
    if ok:
        return None
    got = 'null' if value is None else f'{kind(value)} {_short(repr(value))}'
    return f'{spec.name} must be {need}, got {got}'


def _short(text: str, limit: int = 200) -> str:
    """``text`` cut to ``limit`` characters (a value quoted in an error line)."""
    return text if len(text) <= limit else f'{text[:limit - 3]}...'


def rejection_to_dict(rejection: Rejection | SetAside) -> dict[str, Any]:
    """JSON-ready form of a set-aside move: ``move_id``, ``target_angle``, ``stamp``, ``reason``."""
    if isinstance(rejection, SetAside):
        return rejection.to_dict()
    return {'move_id': int(rejection.move_id),
            'target_angle': finite_or_none(rejection.target_angle),
            'stamp': finite_or_none(rejection.stamp), 'reason': rejection.reason}


@dataclass(frozen=True)
class WindowResult:
    """One identified window.

    Attributes:
        window_index: The windower's running number of the window.
        target_angle: Signed target angle [deg].
        partial: Identified from an unfinished window at the end of the bag.
        first_stamp: Stamp of the window's earliest move [s].
        last_stamp: Stamp of its latest move [s].
        result: The identification.
        drift: The drift monitor's verdict.
    """

    window_index: int
    target_angle: float
    partial: bool
    first_stamp: float
    last_stamp: float
    result: IdentificationResult
    drift: DriftVerdict

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``window_index``, the result's fields, ``partial``, stamps, ``drift``."""
        out: dict[str, Any] = {'window_index': self.window_index}
        out.update(self.result.to_dict())
        out['partial'] = self.partial
        out['first_stamp'] = self.first_stamp
        out['last_stamp'] = self.last_stamp
        out['drift'] = self.drift.to_dict()
        return out


@dataclass(frozen=True)
class MismatchedWindow:
    """A window whose data do not match the plant model (not identified).

    Attributes:
        window_index: The windower's running number of the window.
        target_angle: Signed target angle [deg].
        moves: Moves in the window.
        reason: Why the data do not match (one line).
    """

    window_index: int
    target_angle: float
    moves: int
    reason: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the fields by name."""
        return {'window_index': self.window_index,
                'target_angle': finite_or_none(self.target_angle), 'moves': self.moves,
                'reason': self.reason}


@dataclass(frozen=True)
class BagIdentification:
    """Everything ``galvo-sysid identify`` found in a bag.

    Attributes:
        info: The bag's topics and time range.
        method: The identification method used.
        window_size: Moves per complete window.
        windows: Identified windows, in the order they were completed.
        pooled: Pooled estimate over all windows (None without windows).
        rejected: Set-aside moves and messages, JSON-ready (see :func:`rejection_to_dict`).
        moves: Move halves read from the bag (current and encoder messages) / 2: the messages
            actually read, whatever the bag's metadata claims.
        pooling: How ``pooled`` was made: ``'joint'`` or ``'inverse-variance'`` (see
            :data:`POOLINGS`; ``''`` without windows).
        pooled_windows: Windows that went into ``pooled``.
        pooling_note: Why the pooling is not the one asked for (e.g. the joint fit failed),
            else None.
        model: The plant-model file used ('': the packaged paper model).
        mismatched: Windows whose data do not match the model.
        model_mismatch: Why the data do not match the model (the first window's reason, or
            that of moves of another sample period), else None.
        reference: The drift monitor's reference model (what deviations are taken from).
        reference_name: How messages name it (its file).
        sample_period: The model's sample period [s].
    """

    info: BagInfo
    method: str
    window_size: int
    windows: tuple[WindowResult, ...]
    pooled: IdentificationResult | None
    rejected: tuple[dict[str, Any], ...]
    moves: float
    pooling: str = ''
    pooled_windows: int = 0
    pooling_note: str | None = None
    model: str = ''
    mismatched: tuple[MismatchedWindow, ...] = ()
    model_mismatch: str | None = None
    reference: ModalModel | None = None
    reference_name: str = ''
    sample_period: float = 1e-5

    @property
    def model_name(self) -> str:
        """How messages name the model (its file, or ``paper_table1 (packaged)``)."""
        return model_label(self.model)

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` object: ``{"windows": [...], "pooled": {...}, "rejected": [...],
        "model": ..., "model_mismatch": ..., "mismatched_windows": [...]}``.

        ``pooled`` holds the result's fields plus ``pooling``, ``pooled_windows`` and
        ``pooling_note``; ``model_mismatch`` says why the data do not match the model (null
        when they do).
        """  # noqa: D205
        pooled = None
        if self.pooled is not None:
            pooled = self.pooled.to_dict()
            pooled.update(pooling=self.pooling, pooled_windows=self.pooled_windows,
                          pooling_note=self.pooling_note)
        return {
            'windows': [w.to_dict() for w in self.windows],
            'pooled': pooled,
            'rejected': list(self.rejected),
            'model': self.model_name,
            'model_mismatch': self.model_mismatch,
            'mismatched_windows': [w.to_dict() for w in self.mismatched],
        }


def identify_bag(bag: str | os.PathLike[str], *, method: str = _SYSID['method'],
                 window_size: int = _SYSID['window_size'], min_partial: int | None = None,
                 namespace: str | None = None, monitor: DriftMonitor | None = None,
                 na: int = _SYSID['na'], nb: int = _SYSID['nb'],
                 windower: Mapping[str, Any] | None = None,
                 jobs: int = 1, pooling: str | None = None,
                 joint_windows: int = JOINT_WINDOWS, model: PlantModel | None = None,
                 model_path: str = '',
                 progress: Callable[[int, int], None] | None = None) -> BagIdentification:
    """Identify every window of moves in a bag (see the module docs for the path taken).

    Args:
        bag: The bag (directory, ``.mcap`` or ``.db3``).
        method: One of :data:`~galvo_sysid.ident.identify.METHODS`; default: the sysid
            node's parameter ``method`` (``'refined'``).
        window_size: Moves per window; default: the sysid node's ``window_size`` (100).
        min_partial: Smallest unfinished window identified at the end; default half a window.
        namespace: Scanner namespace when the bag holds several.
        monitor: Drift monitor (default: reference = the model, default tolerances).
        na: ARX order of A[q] (paper pipeline, also the refined fit's start); default: the
            sysid node's parameter ``na``.
        nb: ARX order of B[q]; default: the sysid node's ``nb``.
        windower: Further :class:`~galvo_sysid.monitor.pairing.MoveWindower` settings, as the
            sysid node's parameters of
            :data:`~galvo_sysid.monitor.parameters.WINDOWER_PARAMETERS` (``window_size`` here
            is overridden by the argument).
        jobs: Windows fitted in parallel by this many forked processes (1: on one thread of
            this process; at most :func:`job_limit`), by
            :class:`~galvo_sysid.monitor.scheduler.WindowScheduler`, the sysid node's. The
            results do not depend on it: each window's fit is the same function call, and
            the outcomes come back in window order (the drift monitor judges the windows in
            order, the lists keep their order).
        pooling: ``'joint'`` (default for ``'refined'``) or ``'inverse-variance'`` (default,
            and the only choice, for the paper methods); see the module docs.
        joint_windows: Windows held for the joint fit at most (memory): beyond, the oldest
            window of the target angle holding the most is let go, so every angle stays in.
        model: The scanner's plant model (default: the paper's): the sample period the
            moves must have, what every window and the joint fit identify.
        model_path: Its file, for the messages ('': the packaged paper model).
        progress: Called as ``progress(messages_done, messages_total)`` while reading.

    Raises:
        BagError: Missing, corrupt or truncated bag, no galvo topics, wrong topic type.
        ConfigurationError: Unknown method or bad window settings.
    """
    from galvo_sysid.model import PAPER_MODEL
    from galvo_sysid.monitor.drift import DriftMonitor
    from galvo_sysid.monitor.pairing import MoveWindower
    from galvo_sysid.monitor.scheduler import WindowScheduler, fit_window

    plant = PAPER_MODEL if model is None else model

    if method not in METHODS:
        msg = f'unknown method {method!r}; choose one of {", ".join(METHODS)}'
        raise ConfigurationError(msg)
    min_moves = window_size // 2 if min_partial is None else int(min_partial)
    if min_moves < 2:  # an average needs two moves
        msg = f'min_partial must be >= 2, got {min_moves}'
        raise ConfigurationError(msg)
    if int(jobs) < 1:
        msg = f'jobs must be >= 1, got {jobs}'
        raise ConfigurationError(msg)
    jobs = min(int(jobs), job_limit()[0])  # more processes than CPUs or memory only cost
    pooling = ('joint' if method == 'refined' else 'inverse-variance') if pooling is None \
        else pooling
    if pooling not in POOLINGS or (pooling == 'joint' and method != 'refined'):
        msg = (f'pooling {pooling!r} is not possible with method {method!r}; choose '
               f'{"one of " + ", ".join(POOLINGS) if method == "refined" else "inverse-variance"}')
        raise ConfigurationError(msg)
    if int(joint_windows) < 1:
        msg = f'joint_windows must be >= 1, got {joint_windows}'
        raise ConfigurationError(msg)
    kept: list[Window] = []  # the joint fit's windows
    settings = {k: v for k, v in dict(windower or {}).items() if k in WINDOWER_PARAMETERS}
    settings['window_size'] = window_size
    settings['sample_period'] = plant.sample_period
    pairer = MoveWindower(**settings)
    judge = DriftMonitor(reference=plant.modal, reference_name=model_label(model_path)) \
        if monitor is None else monitor
    rejected: list[dict[str, Any]] = []
    mismatched: list[MismatchedWindow] = []
    # exactly the sysid node's fit function (nodes/sysid_node.py: SysidNode._fit_function)
    fit = functools.partial(fit_window, method=method, model=plant,
                            options={'na': int(na), 'nb': int(nb)})
    windows: list[WindowResult] = []
    # where each window's set-aside moves go in `rejected`: where they went when each window
    # was fitted as soon as it completed (so the list does not depend on the timing)
    marks: dict[int, int] = {}
    late: list[tuple[int, list[dict[str, Any]]]] = []

    def handle(outcome: FitOutcome) -> None:
        """Judge one window's outcome (called in window order)."""
        window = outcome.window
        err = outcome.exception
        if outcome.result is None:
            if outcome.mismatch:  # said plainly: the scanner is another one
                why = one_line(err) if err is not None else outcome.error or ''
                mismatched.append(MismatchedWindow(window.index, window.target_angle,
                                                   window.moves, why))
                reason = f'window {window.index} does not match the model: {why}'
            else:  # like the sysid node: a failed fit loses its window only
                text = _failure(err, outcome.error)
                reason = f'window {window.index} not identified: {text}'
            late.append((marks.pop(window.index), [
                {'move_id': mid, 'target_angle': window.target_angle, 'stamp': None,
                 'reason': reason} for mid in window.move_ids]))
            return
        screened = outcome.result.set_aside
        late.append((marks.pop(window.index), [
            {'move_id': window.move_ids[i], 'target_angle': window.target_angle, 'stamp': None,
             'reason': f'window {window.index}: move set aside by the screening: {why}'}
            for i, why in screened]))
        verdict = judge.assess(outcome.result, window_index=window.index)
        windows.append(WindowResult(window.index, window.target_angle, window.partial,
                                    window.first_stamp, window.last_stamp, outcome.result,
                                    verdict))
        if pooling == 'joint':
            _keep(kept, window, limit=int(joint_windows))

    # the children are forked: they inherit the imported numerics (no ROS in this process)
    with WindowScheduler(fit, processes=int(jobs) if int(jobs) > 1 else 0,
                         queue_size=int(jobs), when_full='wait', ordered=True,
                         start_method='fork', warm_up=False) as scheduler:

        def submit(window: Window) -> None:
            marks[window.index] = len(rejected)
            scheduler.submit(window)
            for outcome in scheduler.take():
                handle(outcome)

        with BagReader(bag) as reader:
            current, encoder = reader.galvo_topics(namespace=namespace)
            info = reader.info
            total = sum(t.count for t in info.topics if t.topic in {current, encoder})
            done = 0  # messages read (what the report counts, not what the bag claims)
            halves = reader.move_halves(namespace=namespace, max_samples=pairer.max_samples)
            for done, item in enumerate(halves, start=1):
                if isinstance(item, SetAside):
                    if item.half is not None:  # refused before decoding: its move set aside
                        pairer.refuse(item.half, item.reason)
                    else:
                        rejected.append(item.to_dict())
                else:
                    for window in pairer.add(item):
                        submit(window)
                rejected.extend(rejection_to_dict(r) for r in pairer.pop_rejections())
                if progress is not None:
                    progress(done, total)
        for window in pairer.flush(min_moves=min_moves):
            submit(window)
        rejected.extend(rejection_to_dict(r) for r in pairer.pop_rejections())
        scheduler.close(timeout=None)
        for outcome in scheduler.take():
            handle(outcome)
    rejected = _insert(rejected, late)
    pooled, used, note, n_pooled = _pooled(windows, kept, pooling=pooling, model=plant)
    why = mismatched[0].reason if mismatched else pairer.period_mismatch
    return BagIdentification(info=info, method=method, window_size=window_size,
                             windows=tuple(windows), pooled=pooled, rejected=tuple(rejected),
                             moves=done / 2, pooling=used if windows else '',
                             pooled_windows=n_pooled,
                             pooling_note=note, model=model_path, mismatched=tuple(mismatched),
                             model_mismatch=why, reference=judge.reference,
                             reference_name=judge.reference_name,
                             sample_period=plant.sample_period)


def _failure(err: BaseException | None, error: str | None) -> str:
    """Why a window's fit failed, one line (the exception's type when unexpected)."""
    if err is None:
        return error or 'unknown reason'
    if isinstance(err, GalvoSysidError):
        return one_line(err)
    return f'unexpected {type(err).__name__}: {one_line(err)}'


def _insert(items: list[dict[str, Any]], late: list[tuple[int, list[dict[str, Any]]]],
            ) -> list[dict[str, Any]]:
    """``items`` with each ``(position, more)`` of ``late`` (positions ascending) inserted."""
    out: list[dict[str, Any]] = []
    start = 0
    for position, more in late:
        out.extend(items[start:position])
        out.extend(more)
        start = position
    out.extend(items[start:])
    return out


def _keep(kept: list[Window], window: Window, *, limit: int) -> None:
    """Hold ``window`` for the joint fit, at most ``limit`` windows in all.

    Beyond the limit, the oldest window of the signed target angle holding the most windows
    goes, so the held windows stay spread over the angles (each excites the modes its own
    way).
    """
    if window.moves < 3:  # the joint fit needs 3 moves per window
        return
    kept.append(window)
    if len(kept) > limit:
        counts = collections.Counter(w.target_angle for w in kept)
        most = max(counts.values())
        drop = next(i for i, w in enumerate(kept) if counts[w.target_angle] == most)
        del kept[drop]


def _pooled(windows: list[WindowResult], kept: list[Window], *, pooling: str,
            model: PlantModel) -> tuple[IdentificationResult | None, str, str | None, int]:
    """(pooled estimate, pooling used, note, windows pooled) of the identified windows.

    A window whose fit is far below the others' (more than 10 points and 5 robust standard
    deviations under their median) fits its data much worse than the same model fits the
    rest: it is left out of the pool, and the note says which.
    """
    from galvo_sysid.ident.identify import identify_joint
    from galvo_sysid.ident.pool import pool_results

    outliers = _poor_fits(windows)
    results = [w.result for w in windows if w.window_index not in outliers]
    kept = [w for w in kept if w.index not in outliers]
    left_out = None
    if outliers:
        left_out = ("left out of the pool for a fit far below the others': " + ', '.join(
            f'window {i} ({fit:.1f} %)' for i, fit in sorted(outliers.items())))
    # the combination of the windows is a good start: the joint fit starts from it as it is
    if not results:
        return None, '', left_out, 0
    combined = pool_results(results)
    if pooling != 'joint':
        return combined, 'inverse-variance', left_out, len(results)
    periods = {w.sample_period for w in kept}
    if len(periods) != 1:
        reason = 'windows of different sample periods' if periods else \
            'no window of 3 moves or more'
        return (combined, 'inverse-variance', _notes(f'joint fit not made ({reason})', left_out),
                len(results))
    try:
        joint = identify_joint([(w.current, w.encoder) for w in kept],
                               sample_period=periods.pop(), initial=combined,
                               target_angle=combined.target_angle, keep_initial_damping=True,
                               model=model)
    except GalvoSysidError as err:
        return (combined, 'inverse-variance',
                _notes(f'joint fit failed: {one_line(err)}', left_out), len(results))
    return joint, 'joint', left_out, len(kept)


def _notes(*notes: str | None) -> str | None:
    text = '; '.join(n for n in notes if n)
    return text or None


def _poor_fits(windows: list[WindowResult]) -> dict[int, float]:
    """Windows whose fit is far below the others' (see :func:`_pooled`), with their fit."""
    import numpy as np

    fits = np.array([w.result.fit_percent for w in windows], dtype=float)
    ok = np.isfinite(fits)
    if np.count_nonzero(ok) < 3:
        return {}
    median = float(np.median(fits[ok]))
    spread = 1.4826 * float(np.median(np.abs(fits[ok] - median)))
    limit = median - max(10.0, 5.0 * spread)
    return {w.window_index: float(f) for w, f in zip(windows, fits, strict=True)
            if not f >= limit}
