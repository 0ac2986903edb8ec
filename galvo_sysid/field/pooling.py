"""The pooled estimate of a bag's windows: one joint fit, or the inverse-variance combination.

The windows held for the joint fit (at most :data:`JOINT_WINDOWS`, spread over the target
angles), the poor fits left out of the pool, and the fallback to the inverse-variance
combination (:func:`~galvo_sysid.ident.pool.pool_results`) when the joint fit
(:func:`~galvo_sysid.ident.identify.identify_joint`) cannot be made; see
:mod:`galvo_sysid.field.offline`.
"""

from __future__ import annotations

import collections
import dataclasses
from typing import TYPE_CHECKING

from galvo_sysid.errors import GalvoSysidError, one_line

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy as np
    from numpy.typing import NDArray

    from galvo_sysid.field.results import WindowResult
    from galvo_sysid.ident.refine.joint import MapWindows
    from galvo_sysid.ident.refine.whitener import NoiseModel
    from galvo_sysid.ident.result import IdentificationResult
    from galvo_sysid.model import PlantModel
    from galvo_sysid.monitor.moves import Window

__all__ = ['JOINT_START', 'JOINT_WINDOWS', 'POOLINGS', 'joint_records']

POOLINGS = ('joint', 'inverse-variance')
"""Pooled estimates: one joint fit to the windows (refined method only), or the
inverse-variance combination of the windows' results."""

JOINT_WINDOWS = 64
"""Windows held for the joint fit at most (about 0.8 MB each for 100 moves of 512 samples)."""

JOINT_START = {'keep_initial_damping': True, 'scan_points': 0}
"""How the joint fit starts: from the windows' pooled results as they are, without scanning
the bands again (each window's fit scanned them; the joint fit's profiles still search every
mode of moderate evidence over its band), and so without its first, unweighted stage. On the
paper bag of 19 angles the same estimates to the last digit as with the scan, 0.08 s less."""


def _keep(kept: list[Window], window: Window, *, limit: int,
          set_aside: Sequence[int] = ()) -> None:
    """Hold ``window`` for the joint fit, at most ``limit`` windows in all.

    The moves its screening set aside (``set_aside``: their indices in the window) are left
    out: the joint fit takes the screened moves as they are (its own screening would find the
    same). Beyond the limit, the oldest window of the signed target angle holding the most
    windows goes, so the held windows stay spread over the angles (each excites the modes
    its own way).
    """
    if set_aside:
        import numpy as np

        keep = np.ones(window.moves, dtype=bool)
        keep[list(set_aside)] = False
        window = dataclasses.replace(
            window, current=window.current[keep], encoder=window.encoder[keep],
            move_ids=tuple(m for m, k in zip(window.move_ids, keep, strict=True) if k))
    if window.moves < 3:  # the joint fit needs 3 moves per window
        return
    kept.append(window)
    if len(kept) > limit:
        counts = collections.Counter(w.target_angle for w in kept)
        most = max(counts.values())
        drop = next(i for i, w in enumerate(kept) if counts[w.target_angle] == most)
        del kept[drop]


def _pooled(windows: list[WindowResult], kept: list[Window], *, pooling: str,
            model: PlantModel, map_windows: MapWindows | None = None,
            ) -> tuple[IdentificationResult | None, str, str | None, int]:
    """(pooled estimate, pooling used, note, windows pooled) of the identified windows.

    ``map_windows`` shares the joint fit's large scans out
    (:attr:`~galvo_sysid.ident.refine.joint.JointProblem.map_windows`).

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
    # the windows were screened when they were fitted (not again), and weighed by the noise
    # models their fits reuse
    by_index = {w.window_index: w.result.noise_model for w in windows}
    try:
        joint = identify_joint(joint_records(kept), sample_period=periods.pop(),
                               initial=combined, target_angle=combined.target_angle,
                               model=model, screen_limit=0.0,
                               noise_models=_noise_models(kept, by_index),
                               map_windows=map_windows, **JOINT_START)
    except GalvoSysidError as err:
        return (combined, 'inverse-variance',
                _notes(f'joint fit failed: {one_line(err)}', left_out), len(results))
    return joint, 'joint', left_out, len(kept)


def joint_records(kept: Sequence[Window]) -> list[tuple[NDArray[np.float64],
                                                         NDArray[np.float64]]]:
    """The held windows' records for the joint fit, the windows of one signed target angle
    and record length as one window (their moves together, in the order held).

    Their average is then over all their moves, as the paper averages the moves of one
    angle: each window's initial conditions and offset are the mean of its moves', so the
    merged window's are the mean of those, and the model is the same. What is given up is
    only what the windows' averages differ by, the same moves' noise; the joint fit's work
    per window (its scans, polishes, covariance) is done once per angle instead of once per
    window. (On the paper's 19 angles x 200 moves, 12 noise seeds in a scratch run, the
    windows merged and apart gave the same rms error over the Cramer-Rao bound of the
    windows apart, to within the seeds' scatter, in 30 % less time.)
    """  # noqa: D205
    import numpy as np

    return [(np.concatenate([w.current for w in g]), np.concatenate([w.encoder for w in g]))
            for g in _same_angle_and_length(kept)]


def _same_angle_and_length(kept: Sequence[Window]) -> list[list[Window]]:
    """The held windows grouped by signed target angle and record length, in the order held."""
    groups: dict[tuple[float, int], list[Window]] = {}
    for w in kept:
        groups.setdefault((w.target_angle, w.current.shape[1]), []).append(w)
    return list(groups.values())


def _noise_models(kept: Sequence[Window], by_index: dict[int, NoiseModel | None]) -> list[
        NoiseModel | None]:
    """Per record of :func:`joint_records`, its window's own fit's noise model: None for
    windows merged there (their moves together are another window)."""  # noqa: D205, D209
    return [by_index.get(g[0].index) if len(g) == 1 else None
            for g in _same_angle_and_length(kept)]


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
