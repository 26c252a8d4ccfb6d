"""HTML fleet summary of ``imu-calib batch``: failures, each parameter across units, outliers."""
from __future__ import annotations

import html
from typing import Any

import numpy as np

from .builder import _png


def _strip_plot(outcomes: list[Any], sp: list[Any], k_sigma: float) -> str:
    """Each unit's deviation from the fleet median in fleet sigmas, per parameter."""
    import matplotlib.pyplot as plt
    ok = {o.unit: o for o in outcomes if o.calib is not None}
    if not ok or not sp:
        return ''
    from ..core.sensor_model import PARAMETER_NAMES
    fig, ax = plt.subplots(figsize=(12, 3.5))
    for j, p in enumerate(sp):
        col = PARAMETER_NAMES.index(p.name)
        for u, o in ok.items():
            s = float(np.hypot(p.sigma, o.calib.sigma.as_vector()[col]))
            z = (o.calib.errors.as_vector()[col] - p.median) / s if s > 0 else 0.0
            ax.plot(j, np.clip(z, -10, 10), '.', color='tab:red' if abs(z) > k_sigma
                    else 'tab:blue', ms=4)
    ax.axhline(k_sigma, color='grey', lw=0.5)
    ax.axhline(-k_sigma, color='grey', lw=0.5)
    ax.set_xticks(range(len(sp)))
    ax.set_xticklabels([p.name.split('.')[-1] for p in sp], rotation=90, fontsize=6)
    ax.set_ylabel('(x - median) / sigma')
    return _png(fig)


def fleet_html(outcomes: list[Any], sp: list[Any], k_sigma: float) -> str:
    """The whole summary as one self-contained HTML page."""
    fails = ''.join(f'<tr><td>{html.escape(o.unit)}</td><td>{html.escape(o.bag)}</td>'
                    f'<td>{html.escape(o.reason)}</td></tr>'
                    for o in outcomes if o.status != 'ok') or '<tr><td colspan=3>none</td></tr>'
    rows = ''.join(
        f'<tr><td>{html.escape(p.name)}</td><td>{p.n}</td><td>{p.median:.4g}</td>'
        f'<td>{p.sigma:.3g}</td><td>{p.minimum:.4g}</td><td>{p.maximum:.4g}</td>'
        f'<td{" style=background:#fcc" if p.outliers else ""}>'
        f'{html.escape(", ".join(f"{u} ({z:+.1f})" for u, z in p.outliers))}</td></tr>'
        for p in sp)
    n_ok = sum(o.status == 'ok' for o in outcomes)
    return f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>IMU fleet</title>
<style>body{{font-family:sans-serif;margin:2em}}td,th{{border:1px solid #ccc;padding:2px 6px}}
table{{border-collapse:collapse}}</style></head><body>
<h1>IMU fleet summary</h1>
<p>{n_ok} of {len(outcomes)} bags calibrated. A unit is flagged in a parameter when it lies
beyond {k_sigma:g} sigma of the fleet (median, sigma = 1.4826 MAD, its own uncertainty
added in quadrature).</p>
{_strip_plot(outcomes, sp, k_sigma)}
<h2>Failures</h2><table><tr><th>unit</th><th>bag</th><th>reason</th></tr>{fails}</table>
<h2>Parameters across the fleet (SI)</h2>
<table><tr><th>parameter</th><th>units</th><th>median</th><th>fleet sigma</th><th>min</th>
<th>max</th><th>beyond {k_sigma:g} sigma</th></tr>{rows}</table>
</body></html>
"""
