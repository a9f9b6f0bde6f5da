"""Where do measurement and simulation disagree? Summaries of the residual r = measured − simulated (″).

* against each signal (torque, angle, angle mod signal period, time, angle rate): the share of the residual
  variance explained by the bin means (correlation ratio η², 0…1) and the binned means themselves;
* direction-even and -odd parts in torque bins: even = ½(r↑ + r↓), odd = ½(r↑ − r↓);
* periodograms of r in the simulated angle and in time (amplitude of the best sinusoid per period).
"""

from __future__ import annotations

import math

import numpy as np

from tcms_daq.discrepancy.design import DesignData

N_BINS = 24


def equal_count_bins(x: np.ndarray, n_bins: int) -> np.ndarray:
    """Bin index (0…) of each sample in about-equal-count bins of ``x``."""
    edges = np.unique(np.quantile(x, np.linspace(0.0, 1.0, n_bins + 1)))
    if len(edges) < 2:
        return np.zeros(len(x), dtype=int)
    return np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)


def _binned(x: np.ndarray, r: np.ndarray, n_bins: int = N_BINS) -> tuple[np.ndarray, np.ndarray, float]:
    """(bin centres, bin means, η²) of r in equal-count bins of x."""
    if np.ptp(x) <= 0 or len(x) < 2 * n_bins:
        return np.zeros(0), np.zeros(0), 0.0
    k = equal_count_bins(x, n_bins)
    cnt = np.bincount(k).astype(float)
    ok = cnt > 0
    mean = np.bincount(k, weights=r)[ok] / cnt[ok]
    centre = np.bincount(k, weights=x)[ok] / cnt[ok]
    var = float(np.var(r))
    eta2 = float(np.sum(cnt[ok] * (mean - r.mean()) ** 2) / (len(r) * var)) if var > 0 else 0.0
    return centre, mean, eta2


def angle_rate(data: DesignData) -> np.ndarray:
    if not data.has_time:
        return np.zeros(len(data))
    if len(data) <= 2:
        return np.zeros(len(data))
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.gradient(data.sim_angle_arcsec, data.time_s)
    return np.where(np.isfinite(rate), rate, 0.0)


def periodogram(x: np.ndarray, r: np.ndarray, periods: np.ndarray) -> np.ndarray:
    """Amplitude (″) of the least-squares sinusoid (with offset) of r at each period in the coordinate x."""
    if len(periods) == 0:
        return np.zeros(0)
    stride = max(1, len(x) // 8000)
    xs, rs = x[::stride], r[::stride] - r[::stride].mean()
    amp = np.empty(len(periods))
    for i, p in enumerate(periods):
        w = 2.0 * math.pi / p * xs
        s, c = np.sin(w), np.cos(w)
        s -= s.mean()
        c -= c.mean()
        a = np.array([[s @ s, s @ c], [s @ c, c @ c]])
        b = np.array([s @ rs, c @ rs])
        try:
            beta = np.linalg.solve(a + 1e-12 * np.eye(2), b)
        except np.linalg.LinAlgError:
            beta = np.zeros(2)
        amp[i] = math.hypot(*beta)
    return amp


def uniform_step_s(time_s: np.ndarray) -> float | None:
    """The sample spacing when ``time_s`` is evenly sampled (99 % of the steps within 1 % of the median), else None."""
    if len(time_s) < 16:
        return None
    dt = np.diff(time_s)
    step = float(np.median(dt))
    if not step > 0:
        return None
    return step if np.mean(np.abs(dt - step) <= 0.01 * step) >= 0.99 else None


def time_lines(time_s: np.ndarray, r: np.ndarray, *, count: int = 3, ratio: float = 25.0
               ) -> list[tuple[float, float, float]]:
    """The strongest sinusoids in time of ``r`` as (period s, amplitude ″, phase rad), from the FFT of the evenly
    sampled record (every sample: a stride would alias a vibration), each refined by least squares at the peak and
    kept when its power is ``ratio`` times the spectrum's median; at most ``count``, strongest first, each removed
    before the next is looked for. Empty when the sampling is uneven."""
    step = uniform_step_s(time_s)
    if step is None:
        return []
    x = np.asarray(r, dtype=float) - float(np.mean(r))
    t = np.asarray(time_s, dtype=float) - float(time_s[0])
    n = len(x)
    n_fft = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfftfreq(n_fft, step)
    low = 2.0 / (n * step)  # at least two cycles in the record
    usable = (f >= low) & (f <= 0.45 / step)
    if not usable.any():
        return []
    window = np.hanning(n)
    out: list[tuple[float, float, float]] = []
    for _ in range(count):
        power = np.abs(np.fft.rfft(x * window, n_fft)) ** 2
        band = np.where(usable, power, 0.0)
        i = int(np.argmax(band))
        if band[i] < ratio * float(np.median(power[usable])):
            break
        if 0 < i < len(power) - 1:  # parabolic refinement of the peak in log power
            a, b, c = np.log(power[i - 1:i + 2] + 1e-300)
            den = a - 2 * b + c
            shift = 0.5 * (a - c) / den if den != 0 else 0.0
            freq = float(f[i] + np.clip(shift, -0.5, 0.5) * (f[1] - f[0]))
        else:
            freq = float(f[i])
        w = 2 * math.pi * freq * t
        basis = np.column_stack((np.sin(w), np.cos(w)))
        coef = np.linalg.lstsq(basis, x, rcond=None)[0]
        x = x - basis @ coef
        out.append((1.0 / freq, float(math.hypot(*coef)), float(math.atan2(coef[1], coef[0]))))
    return out


def localise(data: DesignData, residual: np.ndarray) -> dict:
    """JSON-ready localisation summary of ``residual`` (see the module docstring)."""
    r = residual - residual.mean()
    signals = {
        "torque_nm": data.torque_nm,
        "angle_arcsec": data.sim_angle_arcsec,
        "angle_mod_signal_period_arcsec": np.mod(data.sim_angle_arcsec, data.signal_period_arcsec),
    }
    if data.has_time:
        signals["time_s"] = data.time_s
        signals["angle_rate_arcsec_per_s"] = angle_rate(data)
    against = {}
    for name, x in signals.items():
        centre, mean, eta2 = _binned(x, r)
        against[name] = {"explained_fraction": eta2, "bin_centre": centre.tolist(), "bin_mean_arcsec": mean.tolist()}
    # direction-even / -odd parts on common torque bins
    up = data.direction > 0
    edges = np.linspace(data.torque_nm.min(), data.torque_nm.max(), N_BINS + 1)
    k = np.clip(np.searchsorted(edges, data.torque_nm, side="right") - 1, 0, N_BINS - 1)
    even, odd, centres = [], [], []
    for b in range(N_BINS):
        m_up = (k == b) & up
        m_dn = (k == b) & ~up
        if m_up.sum() >= 2 and m_dn.sum() >= 2:
            ru, rd = r[m_up].mean(), r[m_dn].mean()
            even.append(0.5 * (ru + rd))
            odd.append(0.5 * (ru - rd))
            centres.append(0.5 * (edges[b] + edges[b + 1]))
    parity = {
        "torque_bin_centre_nm": centres,
        "even_arcsec": even,
        "odd_arcsec": odd,
        "even_rms_arcsec": float(np.sqrt(np.mean(np.square(even)))) if even else None,
        "odd_rms_arcsec": float(np.sqrt(np.mean(np.square(odd)))) if odd else None,
    }
    span = float(np.ptp(data.sim_angle_arcsec))
    out = {"against": against, "direction_parts": parity}
    if span > 0:
        p_angle = np.geomspace(max(2.0, data.signal_period_arcsec / 8), max(span, 4.0), 160)
        amp = periodogram(data.sim_angle_arcsec, r, p_angle)
        i = int(np.argmax(amp))
        out["periodogram_angle"] = {"period_arcsec": p_angle.tolist(), "amplitude_arcsec": amp.tolist(),
                                    "peak_period_arcsec": float(p_angle[i]), "peak_amplitude_arcsec": float(amp[i])}
    if data.has_time and np.ptp(data.time_s) > 0:
        dt = np.diff(data.time_s)
        step = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0
        p_time = np.geomspace(4 * step, float(np.ptp(data.time_s)), 120)
        amp = periodogram(data.time_s, r, p_time)
        i = int(np.argmax(amp))
        out["periodogram_time"] = {"period_s": p_time.tolist(), "amplitude_arcsec": amp.tolist(),
                                   "peak_period_s": float(p_time[i]), "peak_amplitude_arcsec": float(amp[i]),
                                   "lines": [{"period_s": p, "amplitude_arcsec": a}
                                             for p, a, _ in time_lines(data.time_s, r)]}
    ranked = sorted(((v["explained_fraction"], k) for k, v in against.items()), reverse=True)
    out["strongest_signal"] = ranked[0][1] if ranked else None
    return out
