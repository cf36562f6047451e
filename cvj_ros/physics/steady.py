"""The steady window: one definition shared by ``cvj-sim simulate``, ``run`` and ``analyze``.

The record is cut into equal consecutive slices; the last slice is the best estimate of the
steady state. A window of slices k0..last (to the end of the record) is *steady* when every
slice in it agrees with the last slice:

* **mean speed drift**: ``|mean_k - mean_last| / |mean over the window|`` of the reference
  speed (rad/s; relative, -; slice means Hann-weighted, see :func:`hann_mean`) is at most ``drift_tol`` (default :data:`DRIFT_TOL`);
* **amplitude change**: ``|A_k - A_last| / max(A_k, A_last, floor)`` of every amplitude
  signal (the reference speed and each torque; ``A = (max - min)/2`` over the slice, Davidbaev
  et al. 2023, section 3.3.2) is at most ``amplitude_tol`` (default :data:`AMPLITUDE_TOL`). ``floor``
  = :data:`SPEED_FLOOR` x the speed's peak magnitude over the record, or
  :data:`TORQUE_FLOOR` x the largest peak magnitude of all the torques (the record's torque
  scale), so amplitudes that small count as zero, not as noise: an ideal joint's speed
  ripple at rounding level (1e-13 of the mean), a road load's torque ripple of 1e-4 of its
  mean, or a free end's torque of 1e-16 N m, whose relative change is meaningless.

Comparing with the last slice, not only neighbours, also catches a slow drift or decay
that changes little per slice but much over the window. The window is the longest such
tail holding at least ``min_slices`` slices: it starts at the earliest slice from which
every slice agrees with the last. When even the last ``min_slices`` slices disagree, the
record never became steady: the window falls back to the last :data:`FALLBACK_FRACTION`
of the record with ``steady`` False, and every report says so (``describe()``). The
slices are equal parts of the record (``n_slices``, default :data:`N_SLICES`) or
``slice_s`` seconds each, ending at the last sample; a slice must span at least one period
of the slowest oscillation of interest, or its amplitude depends on the phase. The
window's start resolution is one slice, 10 % of the record by default. A slice with fewer
than 2 samples (it fell in a gap of the record: ticks not recorded) cannot be compared, so
the window is a tail of the slices after the last such slice (:func:`usable_tail`).

Pure numpy, no ROS. Units: times s, speeds rad/s, torques N m.
"""
from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

N_SLICES = 10               # record cut into 10 equal slices (window resolution 10 % of the record)
MIN_SLICES = 3              # a window holds >= 3 slices
DRIFT_TOL = 2.0e-3          # slice mean speeds within 0.2 % of the last slice's
AMPLITUDE_TOL = 0.05        # slice amplitudes within 5 % of the last slice's
SPEED_FLOOR = 1.0e-6        # speed amplitudes below 1e-6 x peak |speed| count as 0 (rounding)
TORQUE_FLOOR = 1.0e-3       # torque amplitudes below 0.1 % of the largest peak |torque| count as 0
FALLBACK_FRACTION = 0.5     # never steady: report on the last half, flagged not steady


@dataclass(frozen=True)
class SteadyWindow:
    """A steady window and the evidence for it.

    ``start_s``/``end_s``: the window (s, sample times). ``steady``: the criterion held over
    it. ``drift``: largest relative mean-speed difference of a window slice from the last
    slice (-); ``amplitude_change``: largest relative amplitude difference from the last
    slice (-) and
    ``amplitude_signal`` the signal it came from. ``slice_s``: slice length (s);
    ``slices``: slices in the window. ``reference``: name of the reference speed.
    ``source``: 'criterion' (found by :func:`find_steady_window`) or 'skip' (the user set
    the start, :func:`skip_window`; ``steady`` is then the criterion's verdict on that
    window, evaluated the same way, for information).
    """

    start_s: float
    end_s: float
    steady: bool
    drift: float
    amplitude_change: float
    amplitude_signal: str
    slice_s: float
    slices: int
    reference: str
    drift_tol: float = DRIFT_TOL
    amplitude_tol: float = AMPLITUDE_TOL
    min_slices: int = MIN_SLICES
    signals: list[str] = field(default_factory=list)
    source: str = 'criterion'

    def mask(self, t: ArrayLike) -> NDArray[np.bool_]:
        """Samples of ``t`` (s) inside the window (at least the last two)."""
        tt = np.asarray(t, dtype=float)
        m = (tt >= self.start_s) & (tt <= self.end_s)
        if np.count_nonzero(m) < 2 and tt.size >= 2:
            m = np.zeros(tt.shape, dtype=bool)
            m[-2:] = True
        return m

    def criterion(self) -> str:
        """The criterion in words, with its thresholds."""
        return (f'steady = over >= {self.min_slices} slices of {self.slice_s:.4g} s to the end, '
                f'every slice within {self.drift_tol:g} of the last slice in mean {self.reference} '
                f'and within {self.amplitude_tol:g} in the amplitude of each signal')

    def describe(self) -> str:
        """One line for reports: the window, the verdict and the measured drift and change."""
        if self.source == 'skip':
            verdict = ('start set by the user, steady by the criterion' if self.steady else
                       'start set by the user, NOT STEADY by the criterion')
        else:
            verdict = 'steady' if self.steady else (
                f'NOT STEADY (criterion never met; last {FALLBACK_FRACTION:.0%} of the record used)')
        if math.isnan(self.drift) and math.isnan(self.amplitude_change):
            # no slices compared (usable_tail): the record is too short, or a gap in it (or
            # a step as long as the slices) leaves too few slices of >= 2 samples at its end
            measured = (f'drift and amplitude change not measurable (fewer than '
                        f'{self.min_slices} slices of {self.slice_s:.4g} s with 2 samples or more '
                        f'each at the end of the record)')
        else:
            measured = (f'drift {self.drift:.2e} (<= {self.drift_tol:g}), amplitude change '
                        f'{self.amplitude_change:.2e} (<= {self.amplitude_tol:g}, '
                        f'{self.amplitude_signal or "-"})')
        slices = (f'{self.slices} slices of {self.slice_s:.4g} s' if self.slices
                  else f'no run of >= {self.min_slices} agreeing slices of {self.slice_s:.4g} s')
        return f'{self.start_s:.4g}..{self.end_s:.4g} s, {verdict}: {measured}, {slices}'

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (adds ``criterion``)."""
        d = asdict(self)
        d['criterion'] = self.criterion()
        return d


def hann_mean(x: FloatArray) -> float:
    """Hann-weighted mean of a slice (weights sin^2(pi (i + 1/2)/n), symmetric): exact for a
    linear trend (its value at the slice's centre), while a partial period of an oscillation
    of amplitude a and angular frequency w leaks only ~a/(w L)^3 into it instead of the plain
    mean's ~a/(w L) (the Hann window's sidelobes fall as 1/f^3), so a slice of a few periods
    does not fake a drift."""
    wts, total = _hann_weights(x.size)
    return float(np.dot(wts, x) / total)


@functools.lru_cache(maxsize=64)
def _hann_weights(n: int) -> tuple[FloatArray, np.float64]:
    """Hann weights of :func:`hann_mean` for a slice of n samples and their sum (cached:
    a record's slices have one or two lengths; the array is read-only)."""
    wts = np.sin(np.pi * (np.arange(n) + 0.5) / n) ** 2
    wts.flags.writeable = False
    return wts, np.sum(wts)


def slice_spans(signals: FloatArray, starts: NDArray[np.intp]) -> FloatArray:
    """max - min of every column of ``signals`` (samples, signals) over the consecutive
    slices ``signals[starts[k]:starts[k+1]]`` (the last to the end); ``starts`` strictly
    increasing. One ``reduceat`` per extremum instead of two reductions per slice and
    signal; max and min are exact, so the spans are the same numbers as per-slice
    ``np.max(x) - np.min(x)`` (NaN propagates the same way)."""
    return (np.maximum.reduceat(signals, starts, axis=0)
            - np.minimum.reduceat(signals, starts, axis=0))


def _slice_edges(t: FloatArray, n_slices: int | None, slice_s: float | None) -> FloatArray:
    """Slice boundaries (s), equal slices ending at t[-1]; the first slice may be cut short
    when ``slice_s`` does not divide the record, and is then dropped."""
    span = float(t[-1] - t[0])
    if slice_s is not None:
        if not (math.isfinite(slice_s) and slice_s > 0.0):
            raise ValueError(f'slice_s: must be a finite number > 0, got {slice_s}')
        n = int(math.floor(span / slice_s + 1e-9))
        return float(t[-1]) - slice_s * np.arange(n, -1, -1, dtype=float)
    n = N_SLICES if n_slices is None else int(n_slices)
    if n < 1:
        raise ValueError(f'n_slices: must be >= 1, got {n_slices}')
    return float(t[0]) + span * np.arange(n + 1, dtype=float) / n


def find_steady_window(t: ArrayLike, reference_speed: ArrayLike, *,
                       amplitude_signals: Mapping[str, ArrayLike] | None = None,
                       reference: str = 'reference speed',
                       n_slices: int | None = None, slice_s: float | None = None,
                       drift_tol: float = DRIFT_TOL, amplitude_tol: float = AMPLITUDE_TOL,
                       min_slices: int = MIN_SLICES, speed_floor: float = SPEED_FLOOR,
                       torque_floor: float = TORQUE_FLOOR) -> SteadyWindow:
    """The steady window of a record (module docstring): ``t`` (s, increasing),
    ``reference_speed`` (rad/s; its mean drift and amplitude are checked),
    ``amplitude_signals`` (name -> series on ``t``, e.g. shaft torques in N m; their
    amplitude change is checked too, with floor ``torque_floor`` x the largest peak of them
    all; the speed's floor is ``speed_floor`` x its own peak).

    Raises:
        ValueError: fewer than 2 samples, mismatched lengths or bad options.
    """
    tt = np.asarray(t, dtype=float)
    w = np.asarray(reference_speed, dtype=float)
    if tt.ndim != 1 or tt.size < 2:
        raise ValueError(f't: need at least 2 samples, got {tt.size}')
    if w.shape != tt.shape:
        raise ValueError(f'reference_speed: {w.shape[0] if w.ndim else 0} samples for {tt.size} times')
    if min_slices < 2:
        raise ValueError(f'min_slices: must be >= 2, got {min_slices}')
    amps: dict[str, tuple[FloatArray, float]] = {reference: (w, speed_floor)}
    for name, series in (amplitude_signals or {}).items():
        arr = np.asarray(series, dtype=float)
        if arr.shape != tt.shape:
            raise ValueError(f'{name}: {arr.size} samples for {tt.size} times')
        amps.setdefault(name, (arr, torque_floor))
    torque_scale = max((float(np.max(np.abs(x))) for k, (x, _) in amps.items() if k != reference),
                       default=0.0)
    edges, lo, hi = slice_bounds(tt, n_slices, slice_s)
    first = usable_tail(lo, hi, min_slices)
    if first is None:
        return window_from_slices(tt, w, lo, hi, edges, None, reference=reference,
                                  drift_tol=drift_tol, amplitude_tol=amplitude_tol,
                                  min_slices=min_slices, signals=list(amps))
    edges, lo, hi = edges[first:], lo[first:], hi[first:]
    # Slice extrema of all signals at once: the slices tile [lo[0], end) (hi[k] = lo[k+1]),
    # so reduceat at lo gives each slice's max / min (exact, as np.max of the slice)
    spans = slice_spans(np.stack([x for x, _ in amps.values()], axis=1), lo)
    stats = [(name, spans[:, col], float(np.max(np.abs(x))) if name == reference else torque_scale,
              rel_floor) for col, (name, (x, rel_floor)) in enumerate(amps.items())]
    return window_from_slices(tt, w, lo, hi, edges, stats, reference=reference,
                              drift_tol=drift_tol, amplitude_tol=amplitude_tol,
                              min_slices=min_slices, signals=list(amps))


def slice_bounds(t: FloatArray, n_slices: int | None = None,
                 slice_s: float | None = None) -> tuple[FloatArray, NDArray[np.intp], NDArray[np.intp]]:
    """``(edges, lo, hi)``: the slice boundaries (s, :func:`_slice_edges`) and each slice's
    sample index range [lo[k], hi[k]) of the increasing times ``t`` (slice k = [edges[k],
    edges[k+1]), the last one closed: hi[-1] = t.size)."""
    edges = _slice_edges(t, n_slices, slice_s)
    lo = np.searchsorted(t, edges[:-1] - 1e-12 * max(1.0, abs(edges[-1])), side='left')
    hi = np.searchsorted(t, edges[1:] - 1e-12 * max(1.0, abs(edges[-1])), side='left')
    hi[-1] = t.size
    return edges, lo, hi


def usable_tail(lo: NDArray[np.intp], hi: NDArray[np.intp], min_slices: int = MIN_SLICES) -> int | None:
    """Index of the first slice of the longest run of slices holding >= 2 samples each that
    ends with the last slice (``lo``/``hi`` from :func:`slice_bounds`), or None when that run
    is shorter than ``min_slices``. A window is a tail of slices, so it can only start after
    the last slice that fell in a gap of the record (a pause in the recorded samples)."""
    bad = np.flatnonzero(hi - lo < 2)
    first = int(bad[-1]) + 1 if bad.size else 0
    return first if lo.size - first >= min_slices else None


def fallback_start(t: FloatArray) -> float:
    """Start (s, a sample time) of the window of a record that never became steady: the last
    :data:`FALLBACK_FRACTION` of it."""
    start = float(t[-1] - FALLBACK_FRACTION * (t[-1] - t[0]))
    return float(t[np.searchsorted(t, start - 1e-12 * max(1.0, abs(start)))])


def window_from_slices(t: FloatArray, w: FloatArray, lo: NDArray[np.intp], hi: NDArray[np.intp],
                       edges: FloatArray,
                       stats: Sequence[tuple[str, FloatArray, float, float]] | None, *,
                       reference: str, drift_tol: float = DRIFT_TOL,
                       amplitude_tol: float = AMPLITUDE_TOL, min_slices: int = MIN_SLICES,
                       signals: Sequence[str] = (),
                       means: FloatArray | None = None) -> SteadyWindow:
    """The criterion of :func:`find_steady_window` on per-slice statistics: ``t`` and the
    reference speed ``w`` in full (the slices' Hann means and the window's mean speed come
    from them), ``lo``/``hi``/``edges`` from :func:`slice_bounds`, and per amplitude signal
    (the reference speed first) ``(name, spans, scale, rel_floor)``: its max - min over each
    slice, its peak magnitude for the floor (the torques: the largest of them all) and the
    relative floor. ``stats`` None: the slices are not usable (too few or too short) - the
    fallback window. ``means``: the slices' Hann means of ``w`` when the caller computed them
    (the dot product's rounding depends on the memory layout of ``w``). Shared by
    :func:`find_steady_window` and the run report, which gathers the torque spans while
    streaming a bag (cvj_ros.orchestrate.report_stream)."""
    tt, n = t, edges.size - 1
    slice_len = float(edges[1] - edges[0]) if n >= 1 else float(tt[-1] - tt[0])

    def fallback(drift: float, change: float, which: str) -> SteadyWindow:
        return SteadyWindow(fallback_start(tt), float(tt[-1]), False, drift, change, which,
                            slice_len, 0, reference, drift_tol, amplitude_tol, min_slices,
                            list(signals))

    if stats is None:
        return fallback(math.nan, math.nan, '')
    if means is None:
        means = np.array([hann_mean(w[a:b]) for a, b in zip(lo, hi)])
    # per slice k: relative amplitude difference from the last slice, worst signal
    change = np.zeros(n)
    worst = [''] * n
    for name, spans, scale, rel_floor in stats:
        floor = max(rel_floor * scale, 1e-300)
        a = 0.5 * spans
        rel = np.abs(a - a[-1]) / np.maximum(np.maximum(a, a[-1]), floor)
        for k in np.flatnonzero(rel > change):
            change[k], worst[k] = rel[k], name
    dmean = np.abs(means - means[-1])

    def window_stats(k0: int) -> tuple[float, float, str]:
        """Worst drift and amplitude change of slices k0..n-1 against the last slice."""
        scale = abs(float(np.mean(w[lo[k0]:])))
        drift = float(np.max(dmean[k0:])) / scale if scale > 0.0 else math.inf
        k = k0 + int(np.argmax(change[k0:]))
        return drift, float(change[k]), worst[k]

    best: int | None = None
    for k0 in range(n - min_slices, -1, -1):    # grow the tail while the criterion holds
        drift, ch, _ = window_stats(k0)
        if drift <= drift_tol and ch <= amplitude_tol:
            best = k0
        else:
            break
    if best is None:
        drift, ch, which = window_stats(n - min_slices)
        return fallback(drift, ch, which)
    drift, ch, which = window_stats(best)
    return SteadyWindow(float(tt[lo[best]]), float(tt[-1]), True, drift, ch, which, slice_len,
                        n - best, reference, drift_tol, amplitude_tol, min_slices, list(signals))


def skip_window(t: ArrayLike, reference_speed: ArrayLike, skip_s: float, *,
                amplitude_signals: Mapping[str, ArrayLike] | None = None,
                reference: str = 'reference speed', **options: Any) -> SteadyWindow:
    """The window [t0 + ``skip_s``, end] set by the user (``--skip``/``--transient``, s),
    with the criterion's drift, amplitude change and verdict evaluated on it (its slices are
    the criterion's slices from the window's start on; all of them must agree with the last).

    Raises:
        ValueError: ``skip_s`` negative or not finite, or the inputs as :func:`find_steady_window`.
    """
    if not (math.isfinite(skip_s) and skip_s >= 0.0):
        raise ValueError(f'skip_s: must be a finite number >= 0, got {skip_s}')
    tt = np.asarray(t, dtype=float)
    w = np.asarray(reference_speed, dtype=float)
    if tt.ndim != 1 or tt.size < 2:
        raise ValueError(f't: need at least 2 samples, got {tt.size}')
    m = tt >= tt[0] + skip_s - 1e-12 * max(1.0, abs(float(tt[-1])))
    if np.count_nonzero(m) < 2:
        m[-2:] = True
    sub = {k: np.asarray(v, dtype=float)[m] for k, v in (amplitude_signals or {}).items()}
    # judge the user's window as one tail: every one of its slices must agree with the last
    # (min_slices = all slices: the criterion's stats then cover the whole window)
    n = _slice_edges(tt[m], options.get('n_slices'), options.get('slice_s')).size - 1
    opts = dict(options, min_slices=max(2, n))
    inner = find_steady_window(tt[m], w[m], amplitude_signals=sub, reference=reference, **opts)
    return SteadyWindow(float(tt[m][0]), float(tt[-1]), inner.steady, inner.drift,
                        inner.amplitude_change, inner.amplitude_signal, inner.slice_s, n, reference,
                        inner.drift_tol, inner.amplitude_tol, inner.min_slices, inner.signals, 'skip')


def joint_state_window(t: ArrayLike, names: Sequence[str], velocity: ArrayLike,
                       effort: ArrayLike, *, skip_s: float | None = None,
                       **options: Any) -> SteadyWindow:
    """The steady window of a JointState record (``/driveline/joint_states`` or an offline
    trace): reference speed = the first shaft (the engine end of the driveline), amplitude
    signals = that speed and every shaft's torque (``effort``, N m). The one choice of
    signals used by ``simulate``, ``run`` and ``analyze``, so one record gives one window.
    ``skip_s`` (s): the user's start instead of the criterion's (:func:`skip_window`).
    ``options`` as :func:`find_steady_window`."""
    vel = np.asarray(velocity, dtype=float)
    eff = np.asarray(effort, dtype=float)
    if not names:
        raise ValueError('names: no shafts')
    torques = {f'{name} torque': eff[:, i] for i, name in enumerate(names)}
    if skip_s is not None:
        return skip_window(t, vel[:, 0], skip_s, amplitude_signals=torques,
                           reference=f'{names[0]} speed', **options)
    return find_steady_window(t, vel[:, 0], amplitude_signals=torques,
                              reference=f'{names[0]} speed', **options)
