"""A simulated unit with known IEEE Std 952 noise terms (test oracle and bench data).

Each axis is the sum of independent processes with the Allan variances of
:mod:`imu_calib_ros.core.noise_fit`:

- quantisation Q: the integrated output (angle) carries an error uniform with variance Q^2,
  independent from sample to sample; the rate sample is its difference over ``tau0``
  (``avar = 3 Q^2 / tau^2`` exactly);
- white noise N: standard deviation ``N / sqrt(tau0)`` per sample (``avar = N^2 / tau``);
- flicker B: one-sided PSD ``B^2 / (pi f)`` from 1/T to the Nyquist frequency, shaped in the
  frequency domain (``avar`` -> ``(2 ln 2 / pi) B^2`` inside the band);
- rate random walk K: a Wiener process of density K (``avar = K^2 tau / 3``);
- rate ramp R and an optional sinusoid (vibration) to break the static assumption.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def simulate_axes(n: int, tau0_s: float, N: float, B: float, K: float, Q: float,
                  rng: np.random.Generator, n_axes: int = 1, R: float = 0.0,
                  sine_amplitude: float = 0.0, sine_hz: float = 0.0) -> FloatArray:
    """``(n, n_axes)`` rate samples (mean over each period) with the given terms."""
    y = rng.normal(0.0, N / math.sqrt(tau0_s), (n, n_axes)) if N > 0 else np.zeros((n, n_axes))
    if Q > 0:
        e = rng.uniform(-math.sqrt(3.0) * Q, math.sqrt(3.0) * Q, (n + 1, n_axes))
        y += np.diff(e, axis=0) / tau0_s
    if B > 0:
        nf = n // 2 + 1
        f = np.fft.rfftfreq(n, tau0_s)
        amp = np.zeros(nf)
        amp[1:] = np.sqrt(B * B / (math.pi * f[1:]) * n / tau0_s / 2.0)
        z = (rng.normal(size=(nf, n_axes)) + 1j * rng.normal(size=(nf, n_axes))) / math.sqrt(2)
        y += np.fft.irfft(z * amp[:, None], n, axis=0)
    if K > 0:
        y += np.cumsum(rng.normal(0.0, K * math.sqrt(tau0_s), (n, n_axes)), axis=0)
    t = np.arange(n)[:, None] * tau0_s
    if R:
        y += R * t
    if sine_amplitude:
        y += sine_amplitude * np.sin(2 * math.pi * sine_hz * t + rng.uniform(0, 2 * math.pi,
                                                                               n_axes))
    return y
