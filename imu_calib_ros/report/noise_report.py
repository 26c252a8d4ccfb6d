"""HTML report of ``imu-calib noise``: the Allan deviations, the fitted model, the terms."""
from __future__ import annotations

import html
from typing import Any

import numpy as np

from .builder import _png


def allan_figure(result: Any) -> str:
    """Two log-log panels (gyro, accelerometer): measured adev per axis, the fitted model,
    the taus left out of the fit (open markers)."""
    import matplotlib.pyplot as plt

    from ..core.noise_characterisation import SENSORS
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, (sensor, col, unit, _) in zip(axes, SENSORS):
        for a, color in enumerate(('tab:red', 'tab:green', 'tab:blue')):
            f = result.fits[col + a]
            ax.loglog(f.tau_s[f.used], f.adev[f.used], '.', color=color, ms=4,
                      label=f'{sensor} {"xyz"[a]}')
            if (~f.used).any():
                ax.loglog(f.tau_s[~f.used], f.adev[~f.used], 'o', mfc='none', color=color,
                          ms=5)
            ax.loglog(f.tau_s, f.model_adev, '-', color=color, lw=0.8)
        ax.set_xlabel('tau [s]')
        ax.set_ylabel(f'Allan deviation [{unit}]')
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle('overlapping Allan deviation (dots), IEEE 952 model (lines), left out '
                 '(circles)', fontsize=9)
    return _png(fig)


def noise_report_html(result: Any, bag: str) -> str:
    """The whole report as one self-contained HTML page."""
    from ..core.noise_characterisation import SENSORS
    from ..core.noise_fit import TERMS
    rows = []
    for sensor, col, _, units in SENSORS:
        for t in TERMS:
            cells = []
            for a in range(3):
                tf = result.fits[col + a].terms[t]
                cells.append(f'{tf.value:.4g} [{tf.low:.3g}, {tf.high:.3g}]' if tf.shown
                             else f'&lt; {tf.high:.3g} (not shown)')
            rows.append(f'<tr><td>{sensor}</td><td>{t}</td><td>{html.escape(units[t])}</td>'
                        + ''.join(f'<td>{c}</td>' for c in cells) + '</tr>')
    warn = ''.join(f'<li>{html.escape(w)}</li>' for w in result.warnings()) or '<li>none</li>'
    c = result.curve
    tau_lo, tau_hi = (c.tau_s[0], c.tau_s[-1]) if len(c.tau_s) else (np.nan, np.nan)
    return f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>IMU noise</title>
<style>body{{font-family:sans-serif;margin:2em}}td,th{{border:1px solid #ccc;padding:2px 6px}}
table{{border-collapse:collapse}}</style></head><body>
<h1>IMU noise characterisation</h1>
<p>bag {html.escape(str(bag))}: {html.escape(result.source)}, {c.duration_s:.0f} s,
{c.n_samples} samples at {result.rate_hz:.6g} Hz; {len(c.tau_s)} taus from
{tau_lo:.3g} s to {tau_hi:.3g} s.</p>
{allan_figure(result)}
<h2>Terms (IEEE Std 952-1997 annex C), 95 % intervals</h2>
<table><tr><th>sensor</th><th>term</th><th>unit</th><th>x</th><th>y</th><th>z</th></tr>
{''.join(rows)}</table>
<h2>Warnings</h2><ul>{warn}</ul>
</body></html>
"""
