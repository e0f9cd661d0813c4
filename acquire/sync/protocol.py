"""Sync protocol analysis: camera latency from projector flashes, image-force offset from taps,
drift from early against late events (see :mod:`~vbfe.acquire.recording.sync_session` for the
recording).

*Flashes.* Each frame's rows are averaged into a brightness profile. Around a projector switch
(host time ``h``) the profile goes from its level before the command to its level after the
light has settled; each frame's share of the new level is compared with the share a switch at
instant ``c`` would give a frame whose rows integrate the light over the exposure window
(centred on the frame's time, rows offset by the rolling-shutter line time). The least-squares
``c`` is the instant the light changed on the frames' clock; a partially exposed frame pins it
to a fraction of the exposure, a switch between two exposures only to the gap (uniform error).
``c − h`` is the flash latency: camera latency plus the projector's own. A frame's share is
trusted to 2% of the flash's contrast (a tap's shading must not fake a partial exposure).

*Taps.* A tap's force onset is a sharp rise above the trocar noise, refined by a one-knot
spline fit (flat before the knot). Its image-motion onset: the frames' leading principal
components (rows normalised, so flashes do not look like motion) are fitted, around the tap,
by a quadratic in the measured force (averaged over the exposure) delayed by a lag; the lag
profile's least-squares minimum is the image-minus-force offset of that tap.

Per kind, the events are combined by an inverse-variance mean after rejecting those further
than 4 robust deviations (median/MAD) from the median, widened when they disagree beyond
their errors; the 95% interval is Student's t with ``n − 1`` degrees of freedom.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.acquire.recording.settings import RecordSettings
from vbfe.acquire.recording.sync_session import DIM_NAME, PATTERN_NAME
from vbfe.acquire.session.reader import FRAME_CORRECTION_ATTR, SessionReader
from vbfe.acquire.sync.corners import (
    _bounds,
    _box,
    _knot_profile,
    _leading_components,
    _vertex,
    force_axis,
)
from vbfe.common.errors import SessionError

_WIDTH = 96  # frames are downscaled to this width
_COMPONENTS = 3
_GRID_S = 0.0001  # flash instants are searched on this grid
_LAG_STEP_S = 0.00025  # tap lags are searched on this grid
_CHI2_95 = 3.841
_REJECT_MADS = 4.0
_FLOOR_S = 0.0001  # no event is trusted to better than this
_SHARE_FLOOR = 0.02  # a frame's share of the new light is not trusted to better than this
_TAP_QUIET_S = 0.3  # a tap onset needs the force at rest this long before
_FORCE_SMOOTH_S = 0.005
_ONSET_SEARCH_S = 0.06  # the force knot is searched this far before the threshold crossing
_TAP_MARGIN_S = 0.4  # frames this far around a tap are fitted


@dataclass(frozen=True)
class ProtocolSettings:
    """Camera facts the flash analysis needs (the ``sync_*`` keys of ``[record]``)."""

    exposure_s: float = 0.0
    line_time_s: float = 0.0  # rolling shutter: delay between consecutive sensor rows
    projector_latency_s: float = 0.0  # known command-to-light delay of the projector

    @classmethod
    def from_record(cls, table: RecordSettings) -> ProtocolSettings:
        """Settings from the ``[record]`` settings."""
        return cls(table.sync_exposure_s, table.sync_line_time_s, table.sync_projector_latency_s)


@dataclass
class EventEstimate:
    """A time combined over events: value, standard error, 95% interval and the evidence."""

    value_s: float
    std_s: float
    ci95_s: tuple[float, float]
    times_s: np.ndarray  # when each event happened (s after the first frame)
    values_s: np.ndarray  # each event's own measurement
    stds_s: np.ndarray
    used: np.ndarray  # bool: kept after outlier rejection

    @property
    def n_used(self) -> int:
        """Events the value rests on."""
        return int(self.used.sum())

    @property
    def half_width_s(self) -> float:
        """Half the 95% interval."""
        return (self.ci95_s[1] - self.ci95_s[0]) / 2


def combine(times_s: np.ndarray, values_s: np.ndarray, stds_s: np.ndarray) -> EventEstimate:
    """Inverse-variance mean of events after median/MAD outlier rejection, with a t interval."""
    from scipy.stats import t as student_t  # here: scipy.stats costs every vbfe command ~0.8 s

    values, stds = np.asarray(values_s, float), np.maximum(np.asarray(stds_s, float), _FLOOR_S)
    if len(values) == 0:
        raise SessionError("no events to combine")
    centre = float(np.median(values))
    spread = 1.4826 * float(np.median(np.abs(values - centre)))
    used = np.abs(values - centre) <= _REJECT_MADS * np.hypot(spread, stds)
    w = 1.0 / stds[used] ** 2
    mean = float(np.sum(w * values[used]) / np.sum(w))
    std = float(np.sqrt(1.0 / np.sum(w)))
    n = int(used.sum())
    if n > 1:
        chi2 = float(np.sum(w * (values[used] - mean) ** 2)) / (n - 1)
        std *= np.sqrt(max(1.0, chi2))
    q = float(student_t.ppf(0.975, max(n - 1, 1)))
    return EventEstimate(
        mean, std, (mean - q * std, mean + q * std), np.asarray(times_s, float), values, stds, used
    )


@dataclass
class Drift:
    """How much a time changed from the first to the second half of the session's events."""

    early: EventEstimate
    late: EventEstimate

    @property
    def change_s(self) -> float:
        """Late minus early."""
        return self.late.value_s - self.early.value_s

    @property
    def ci95_s(self) -> tuple[float, float]:
        """95% interval of the change (the halves' half-widths added in quadrature)."""
        half = float(np.hypot(self.early.half_width_s, self.late.half_width_s))
        return self.change_s - half, self.change_s + half


def early_late(estimate: EventEstimate, min_events: int = 3) -> Drift | None:
    """Split the events at the median event time; None with fewer than ``min_events`` a half."""
    times = estimate.times_s
    mid = float(np.median(times))
    halves = [times < mid, times >= mid]
    if min(int(h.sum()) for h in halves) < min_events:
        return None
    early, late = (combine(times[h], estimate.values_s[h], estimate.stds_s[h]) for h in halves)
    return Drift(early, late)


@dataclass
class ProtocolResult:
    """What a sync protocol session measured."""

    offset: EventEstimate | None  # image minus force, from the taps
    flash_latency: EventEstimate | None  # light change in (uncorrected) frame time − command
    camera_latency_s: float | None  # flash latency minus the configured projector latency
    offset_drift: Drift | None
    latency_drift: Drift | None
    taps_found: int
    flashes_shown: int
    flashes_seen: int


def frame_signals(reader: SessionReader) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: mean brightness of each row of the downscaled grey left image (frames ×
    rows) and the leading principal components of the row-normalised image (frames × 3)."""
    width, height = reader.frame_size
    size = (min(_WIDTH, width), max(1, round(height * min(_WIDTH, width) / width)))
    rows, pixels = [], []
    for frame in reader.iter_frames():
        grey = cv2.resize(
            cv2.cvtColor(frame.left, cv2.COLOR_BGR2GRAY), size, interpolation=cv2.INTER_AREA
        ).astype(np.float32)
        mean = grey.mean(axis=1, keepdims=True)
        rows.append(mean[:, 0])
        pixels.append(((grey - mean) / np.maximum(grey.std(axis=1, keepdims=True), 1.0)).ravel())
    x = np.asarray(pixels, np.float32)
    x -= x.mean(axis=0)
    return np.asarray(rows, np.float64), _leading_components(x, _COMPONENTS)


def _row_delays(n_rows: int, sensor_rows: int, line_time_s: float) -> np.ndarray:
    """Exposure-centre delay of each downscaled row against the frame's (middle row's) time."""
    centre = (np.arange(n_rows) + 0.5) * sensor_rows / n_rows - 0.5
    return (centre - (sensor_rows - 1) / 2) * line_time_s


def _exposed_share(
    t: np.ndarray, delays: np.ndarray, change: np.ndarray, exposure_s: float
) -> np.ndarray:
    """Share of each frame-row exposure (frames ``t`` × rows) after a light change at each
    instant of ``change`` (grid × frames × rows)."""
    start = t[None, :, None] + delays[None, None, :] - exposure_s / 2
    if exposure_s <= 0:
        return (start >= change[:, None, None]).astype(np.float32)
    return np.clip((start + exposure_s - change[:, None, None]) / exposure_s, 0.0, 1.0)


def flash_instant(
    t: np.ndarray,
    brightness: np.ndarray,
    h: float,
    window: tuple[float, float],
    settings: ProtocolSettings,
    sensor_rows: int,
    max_lag_s: float,
) -> tuple[float, float] | None:
    """When the light changed after a projector command at ``h`` (frames' clock, s) and its
    standard error; None when the switch is not seen. ``window``: the light is steady from
    the previous switch's settling to the next command."""
    e = settings.exposure_s
    delays = _row_delays(brightness.shape[1], sensor_rows, settings.line_time_s)
    reach = e / 2 + float(np.abs(delays).max())
    pre = (t >= max(h - 0.3, window[0])) & (t + reach < h)
    post = (t - reach > h + max_lag_s) & (t < min(window[1], h + max_lag_s + 0.5))
    if pre.sum() < 2 or post.sum() < 2:
        return None
    before, after = np.median(brightness[pre], axis=0), np.median(brightness[post], axis=0)
    contrast = after - before
    noise = max(1.4826 * float(np.median(np.abs(brightness[pre] - before))), 0.3)
    rows = np.abs(contrast) > 10 * noise
    if not rows.any():
        return None
    near = (t + reach >= h) & (t - reach <= h + max_lag_s)
    share = (brightness[near][:, rows] - before[rows]) / contrast[rows]
    steady = np.concatenate(
        [
            (brightness[pre][:, rows] - before[rows]) / contrast[rows],
            (brightness[post][:, rows] - after[rows]) / contrast[rows],
        ]
    )
    sigma = max(1.4826 * float(np.median(np.abs(steady))), _SHARE_FLOOR)
    change = h + np.arange(0.0, max_lag_s, _GRID_S)
    predicted = _exposed_share(t[near], delays[rows], change, e)
    sse = np.sum((share[None] - predicted) ** 2, axis=(1, 2))
    k = int(np.argmin(sse))
    # rows of one frame err together (a tap's shading, flicker): the threshold counts frames
    low, high = _bounds(np.flatnonzero(sse - sse[k] <= _CHI2_95 * sigma**2 * rows.sum()), k)
    if low == 0 or high == len(change) - 1:
        return None
    return (change[low] + change[high]) / 2, (high - low + 1) * _GRID_S / np.sqrt(12)


def tap_onsets(t_force: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Force onsets of the taps (s), their standard errors, and where each tap ends: the force
    rises above the noise (8 σ of the smoothed force, at least 5% of the largest tap) after
    ``_TAP_QUIET_S`` at rest; the onset is the knot of a spline flat before it."""
    step = float(np.median(np.diff(t_force)))
    width = max(1, int(round(_FORCE_SMOOTH_S / step)))
    dev = force - np.median(force)
    if abs(dev.min()) > abs(dev.max()):
        dev = -dev
    sigma = 1.4826 * float(np.median(np.abs(np.diff(dev)))) / np.sqrt(2)
    smooth = _box(dev, width)
    threshold = max(8 * sigma / np.sqrt(width), 0.05 * float(smooth.max()))
    above = smooth > threshold
    rises = np.flatnonzero(above[1:] & ~above[:-1]) + 1
    falls = np.flatnonzero(~above[1:] & above[:-1]) + 1
    onsets, stds, ends = [], [], []
    last_end = -np.inf
    for i in rises:
        end = falls[falls > i]
        end_t = float(t_force[end[0]]) if len(end) else float(t_force[-1])
        quiet = t_force[i] - last_end >= _TAP_QUIET_S
        last_end = end_t
        if not quiet or t_force[i] - t_force[0] < _TAP_QUIET_S:
            continue
        rise = smooth[i : int(np.searchsorted(t_force, end_t)) + 1]
        peak = i + int(np.argmax(rise >= 0.6 * rise.max()))
        fit = (t_force >= t_force[i] - 0.25) & (t_force <= t_force[peak])
        knots = t_force[i] + np.arange(-_ONSET_SEARCH_S, 0.002, 0.0001)
        onset, std = _knot_profile(t_force[fit], dev[fit], knots, 0.1, "before")
        if np.isfinite(std):
            onsets.append(onset)
            stds.append(std)
            ends.append(end_t)
    return np.array(onsets), np.array(stds), np.array(ends)


def tap_lag(
    t_frames: np.ndarray,
    components: np.ndarray,
    t_force: np.ndarray,
    template: np.ndarray,
    window: tuple[float, float],
    max_lag_s: float,
    correction_s: float = 0.0,
) -> tuple[float, float] | None:
    """Lag (s) of the image motion behind the force over one tap, and its standard error: the
    frames' components in ``window`` fitted by a quadratic in the delayed force template. The
    frames are chosen, and the lags searched, on their times before ``correction_s`` (already
    in ``t_frames``), so a stored correction shifts the lag by itself and changes nothing else
    (the grid moves with it: the fit's sub-step interpolation and interval are the same)."""
    inside = (t_frames + correction_s >= window[0]) & (t_frames + correction_s <= window[1])
    if inside.sum() < 10:
        return None
    t, c = t_frames[inside], components[inside]
    lags = np.arange(-max_lag_s, max_lag_s + 1e-9, _LAG_STEP_S) - correction_s
    x = np.interp(t[None, :] - lags[:, None], t_force, template)
    design = np.stack([np.ones_like(x), x, x * x], axis=2)
    normal = np.einsum("gnp,gnq->gpq", design, design) + 1e-9 * np.eye(3)
    coef = np.linalg.solve(normal, np.einsum("gnp,nc->gpc", design, c))
    rss = np.sum((c[None] - design @ coef) ** 2, axis=1)
    deviance = len(t) * np.sum(np.log(np.maximum(rss, 1e-300)), axis=1)
    k = int(np.argmin(deviance))
    low, high = _bounds(np.flatnonzero(deviance - deviance[k] <= _CHI2_95), k)
    if low == 0 or high == len(lags) - 1:
        return None
    lag = float(lags[0] + _vertex(deviance, k) * _LAG_STEP_S)
    return lag, (high - low + 1) * _LAG_STEP_S / (2 * 1.96)


def analyse_protocol(
    reader: SessionReader, settings: ProtocolSettings, max_lag_s: float = 0.3
) -> ProtocolResult:
    """Flash latency, tap offset and their drifts of a sync protocol session."""
    t_frames_ns = reader.frame_times_ns()
    t0 = int(t_frames_ns[0])
    t_frames = (t_frames_ns - t0) / 1e9
    correction_s = int(reader.analysis().get(FRAME_CORRECTION_ATTR, 0)) / 1e9
    brightness, components = frame_signals(reader)
    sensor_rows = reader.frame_size[1]
    events = [e for e in reader.projector_events()[1:] if e.pattern in (PATTERN_NAME, DIM_NAME)]
    commands = np.array([(e.t_host_ns - t0) / 1e9 for e in events])
    flashes = []
    for i, h in enumerate(commands):
        window = (
            commands[i - 1] + max_lag_s if i else -np.inf,
            commands[i + 1] if i + 1 < len(commands) else np.inf,
        )
        found = flash_instant(
            t_frames + correction_s, brightness, float(h), window, settings, sensor_rows, max_lag_s
        )
        if found is not None:
            flashes.append((h, found[0] - h, found[1]))
    flash_latency = combine(*map(np.array, zip(*flashes, strict=False))) if flashes else None

    t_force = (reader.force_times_ns() - t0) / 1e9
    force = force_axis(reader.forces_n())
    onsets, onset_stds, ends = tap_onsets(t_force, force)
    sign = 1.0 if np.abs(force.max()) >= np.abs(force.min()) else -1.0
    step = float(np.median(np.diff(t_force)))
    template = _box(
        sign * (force - np.median(force)), max(1, int(round(settings.exposure_s / step)))
    )
    taps = []
    for j, (onset, std) in enumerate(zip(onsets, onset_stds, strict=False)):
        window = (
            max(onset - _TAP_MARGIN_S, ends[j - 1] + 0.1 if j else -np.inf),
            min(ends[j] + _TAP_MARGIN_S, onsets[j + 1] - 0.1 if j + 1 < len(onsets) else np.inf),
        )
        found = tap_lag(t_frames, components, t_force, template, window, max_lag_s, correction_s)
        if found is not None:
            taps.append((onset, found[0], float(np.hypot(found[1], std))))
    offset = combine(*map(np.array, zip(*taps, strict=False))) if taps else None
    return ProtocolResult(
        offset=offset,
        flash_latency=flash_latency,
        camera_latency_s=(
            flash_latency.value_s - settings.projector_latency_s if flash_latency else None
        ),
        offset_drift=early_late(offset) if offset else None,
        latency_drift=early_late(flash_latency) if flash_latency else None,
        taps_found=len(onsets),
        flashes_shown=len(events),
        flashes_seen=len(flashes),
    )
