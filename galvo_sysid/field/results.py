"""What identifying a bag gives: the windows, the pooled estimate, what was set aside.

:class:`BagIdentification` (the ``--json`` object of ``galvo-sysid identify``) holds
:class:`WindowResult` per identified window and :class:`MismatchedWindow` per window whose
data do not match the model; :func:`rejection_to_dict` is a set-aside move in JSON.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from galvo_sysid.field.bags import BagInfo, SetAside
from galvo_sysid.jsonsafe import finite_or_none
from galvo_sysid.model import model_label

if TYPE_CHECKING:
    from galvo_sysid.ident.commission import FrequencyResponse
    from galvo_sysid.ident.result import IdentificationResult
    from galvo_sysid.model import InputDynamics, ModalModel
    from galvo_sysid.monitor.rejections import Rejection
    from galvo_sysid.monitor.verdict import DriftVerdict

__all__ = ['BagIdentification', 'MismatchedWindow', 'WindowResult', 'rejection_to_dict']


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
            :data:`~galvo_sysid.field.pooling.POOLINGS`; ``''`` without windows).
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
        dynamics: The model's input dynamics (what the windows' responses are drawn with).
        warn_fraction: The drift monitor's WARN threshold, as a fraction of each tolerance.
        response: The measured frequency response of the first windows' averaged moves, if
            asked for (``identify_bag(response_windows=...)``, for the plot; not in JSON).
        measured_lag: The amplifier lag [s] the windows' measured currents were made into
            held currents with (None: the current was the command).
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
    dynamics: InputDynamics | None = None
    warn_fraction: float = 0.5
    response: FrequencyResponse | None = None
    measured_lag: float | None = None

    @property
    def model_name(self) -> str:
        """How messages name the model (its file, or ``paper_table1 (packaged)``)."""
        return model_label(self.model)

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` object: ``{"windows": [...], "pooled": {...}, "rejected": [...],
        "model": ..., "model_mismatch": ..., "mismatched_windows": [...],
        "measured_current_lag": ...}``.

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
            'measured_current_lag': self.measured_lag,
        }
