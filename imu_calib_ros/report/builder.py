"""HTML report: methods vs truth table, convergence, Kozlov Fig. 4 analogue, SRT windows.

Every plot is a matplotlib (Agg) PNG embedded as a base64 ``data:`` URI so the page is one
self-contained file. Plots whose data a calibration file does not carry are skipped with a
note on the page (e.g. no ``extra.history`` -> no convergence plot).
"""
from __future__ import annotations

import base64
import html
import io
from typing import Any, Sequence

import matplotlib
import numpy as np

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402

from ..core.sensor_model import KEY_OF_FIELD  # noqa: E402
from ..core.units import ENGINEERING, UG_M_S2  # noqa: E402

#: (SensorErrors field, label, factor to engineering units, unit, CONTRACT 4 key)
ROWS = tuple((field, ENGINEERING[key][0], 1.0 / ENGINEERING[key][1],
              ENGINEERING[key][2].replace('|', '/'), key) for field, key in KEY_OF_FIELD.items())


def _srt_not_estimated(res: Any) -> set[tuple[str, tuple[int, ...]]] | None:
    """Entry-level (field, index) pairs an SRT result held fixed, or None if not an SRT file.

    CONTRACT 4's ``fixed`` lists whole keys: one unexcited entry (e.g. ``ba_x``) puts all of
    ``accelerometer.bias`` there, while the SRT's ``extra.srt.not_estimated`` names entries.
    """
    names = (getattr(res, 'extra', None) or {}).get('srt', {}).get('not_estimated')
    if names is None:
        return None
    from ..core.methods.srt import CONSIDER, PARAMS
    out = {(fld, tuple(idx)) for n, fld, idx in PARAMS if n in names}
    out |= {(fld, tuple(idx)) for _, fld, idx, _ in CONSIDER}
    for n, fld, idx in PARAMS:  # Kg is symmetric: both halves
        if n in names and fld == 'gyro_scale_misalignment':
            out.add((fld, tuple(idx[::-1])))
    return out


def is_fixed(res: Any, fld: str, key: str, idx: tuple[int, ...]) -> bool:
    """True when ``res`` held this entry at its prior (not estimated from the data)."""
    entries = _srt_not_estimated(res)
    if entries is not None and key not in ('gyroscope.bias',):
        return (fld, tuple(idx)) in entries
    return key in tuple(getattr(res, 'fixed', ()))


#: micro-g per m/s^2 (standard gravity)
UG_PER_M_S2 = 1.0 / UG_M_S2


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format='png', dpi=90, bbox_inches='tight')
    plt.close(fig)
    return ('<img alt="plot" src="data:image/png;base64,'
            + base64.b64encode(buf.getvalue()).decode('ascii') + '"/>')


def _entries(fld: str) -> list[tuple[int, ...]]:
    if fld in ('gyro_scale_misalignment',):
        return [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    if fld in ('accel_scale_misalignment', 'gyro_g_sensitivity_rad_s_per_m_s2'):
        return [(i, j) for i in range(3) for j in range(3)]
    if fld == 'size_effect_m':
        return [(i, j) for i in range(3) for j in range(3) if i != j]
    return [(i,) for i in range(3)]


def comparison_table(results: Sequence[tuple[str, Any]], truth: Any | None) -> str:
    """Side-by-side table: value, sigma and (with truth) error and error/sigma per method.

    An entry a method held fixed shows ``fixed`` in its error columns (its sigma is the
    prior's, so err/sigma against it says nothing about the method); only estimated
    entries with ``|err/sigma| > 3`` are highlighted.
    """
    head = '<tr><th>parameter</th><th>unit</th>'
    if truth is not None:
        head += '<th>truth</th>'
    for name, _ in results:
        head += (f'<th>{html.escape(name)}</th><th>&sigma;</th>'
                 + ('<th>err</th><th>err/&sigma;</th>' if truth is not None else ''))
    rows = [head + '</tr>']
    # biases: the turn-on value plus the simulated drift at the end, which the EKF tracks;
    # the papers' methods average over their windows instead, so for them this truth is off
    # by the in-run drift (nav grade: 0.0005 deg/h, 2 ug Gauss-Markov sigma)
    tracked = truth.tracked_truth() if truth is not None else None
    for fld, label, k, unit, key in ROWS:
        for idx in _entries(fld):
            tag = label + '[' + ','.join('xyz'[i] for i in idx) + ']'
            r = f'<tr><td>{tag}</td><td>{unit}</td>'
            tv = None
            if truth is not None:
                tv = float(np.asarray(getattr(tracked, fld))[idx]) * k
                r += f'<td>{tv:.4g}</td>'
            for _, res in results:
                v = float(np.asarray(getattr(res.errors, fld))[idx]) * k
                s = float(np.asarray(getattr(res.sigma, fld))[idx]) * k
                fixed = is_fixed(res, fld, key, idx)
                cell = ' class="fixed"' if fixed else ''
                r += f'<td{cell}>{v:.4g}</td><td{cell}>{s:.3g}</td>'
                if tv is None:
                    continue
                if fixed:
                    r += '<td class="fixed" colspan="2">fixed</td>'
                    continue
                z = (v - tv) / s if s > 0 else float('nan')
                cls = ' class="bad"' if np.isfinite(z) and abs(z) > 3 else ''
                r += f'<td>{v - tv:.3g}</td><td{cls}>{z:.2f}</td>'
            rows.append(r + '</tr>')
    return '<table>' + '\n'.join(rows) + '</table>'


def srt_plot(extra: dict[str, Any]) -> str | None:
    """Stationary-window accelerations per SRT sequence: measured Delta a_H and residual."""
    seqs = extra.get('srt', {}).get('sequences')
    if not seqs:
        return None
    labels, meas, res, sig = [], [], [], []
    for s in seqs:
        for row, m, r, sg in zip(s['rows'], s['delta_a_h_m_s2'], s['residual_m_s2'],
                                 s['sigma_m_s2']):
            labels.append(row)
            meas.append(m * UG_PER_M_S2)
            res.append(r * UG_PER_M_S2)
            sig.append(sg * UG_PER_M_S2)
    fig, ax = plt.subplots(2, 1, figsize=(12, 6), sharex=True)
    x = np.arange(len(labels))
    ax[0].bar(x, meas)
    ax[0].set_ylabel('Delta a_H [ug]')
    ax[0].set_title('SRT horizontal acceleration change per sequence (start-frame, eq. 1), '
                    'as measured before the SRT correction')
    ax[1].errorbar(x, res, yerr=3 * np.array(sig), fmt='o', ms=3)
    ax[1].axhline(0, color='k', lw=0.5)
    ax[1].set_ylabel('residual after fit [ug]\n(3 sigma bars)')
    for a in ax:  # ug values, not a matplotlib offset/scale factor hiding the unit
        a.ticklabel_format(axis='y', style='plain', useOffset=False)
    ax[1].set_xticks(x, labels, rotation=90, fontsize=6)
    return _png(fig)


def velocity_plot(extra: dict[str, Any]) -> str | None:
    """Navigated velocity per oscillation cycle (Kozlov & Kapralov Fig. 4 analogue)."""
    cycles = extra.get('oscillation', {}).get('cycles')
    if not cycles:
        return None
    fig, axes = plt.subplots(1, len(cycles), figsize=(3.2 * len(cycles), 3), squeeze=False)
    for ax, c in zip(axes[0], cycles):
        t = np.asarray(c['nav_t_s'])
        v = np.asarray(c['nav_v_enu_m_s'])
        ax.plot(t - t[0], v[:, 0], label='v_E')
        ax.plot(t - t[0], v[:, 1], label='v_N')
        ax.set_title(f"{c['up_axis']} up, T={c['period_s']:.1f} s", fontsize=8)
        ax.set_xlabel('t [s]')
    axes[0][0].set_ylabel('navigated velocity [m/s]')
    axes[0][0].legend(fontsize=7)
    return _png(fig)


def convergence_plot(extra: dict[str, Any]) -> str | None:
    """Estimate history with 3-sigma bands if ``extra.history`` is present.

    Accepted layout: ``{'t_s': [...], 'names': [...], 'value': [[...]], 'sigma': [[...]]}``.
    """
    h = extra.get('history')
    if not isinstance(h, dict) or not {'t_s', 'value', 'sigma'} <= set(h):
        return None
    t = np.asarray(h['t_s'], float)
    v = np.asarray(h['value'], float)
    s = np.asarray(h['sigma'], float)
    names = h.get('names') or [str(i) for i in range(v.shape[1])]
    n = min(v.shape[1], 12)
    fig, axes = plt.subplots((n + 3) // 4, 4, figsize=(14, 2.4 * ((n + 3) // 4)),
                             squeeze=False)
    for i in range(n):
        ax = axes[i // 4][i % 4]
        ax.plot(t, v[:, i])
        ax.fill_between(t, v[:, i] - 3 * s[:, i], v[:, i] + 3 * s[:, i], alpha=0.3)
        ax.set_title(names[i], fontsize=8)
    return _png(fig)


def selfcheck_table(extra: dict[str, Any]) -> str | None:
    """The run's self-check (``provenance.self_check``, issue 17) as a table, or None."""
    v = (extra.get('provenance', {}) or {}).get('self_check')
    if not isinstance(v, dict):
        return None
    rows = ['<tr><th>check</th><th>value</th><th>limit</th><th>reading</th></tr>']
    for name, c in (v.get('checks') or {}).items():
        cls = '' if c.get('passed') else ' class="bad"'
        val, lim = (f'{x:.4g}' if isinstance(x, (int, float)) else '-'
                    for x in (c.get('value'), c.get('limit')))
        rows.append(f'<tr{cls}><td>{html.escape(str(name))}</td><td>{val}</td><td>{lim}</td>'
                    f'<td>{html.escape(str(c.get("text", "")))}</td></tr>')
    cls = '' if v.get('passed') else ' class="bad"'
    head = f'<p{cls}>{html.escape(str(v.get("summary", "")))}</p>'
    return head + '<table>' + ''.join(rows) + '</table>'


def build_report(calib: Any, truth: Any | None = None,
                 compare: Sequence[tuple[str, Any]] = (), title: str = 'IMU calibration',
                 nav_velocity: tuple[np.ndarray, np.ndarray] | None = None) -> str:
    """The HTML page as a string.

    Parameters
    ----------
    calib : CalibrationResult
        The main result; ``extra`` may carry ``srt``, ``oscillation`` and ``history``.
    truth : CalibrationResult, optional
        Simulator truth for the error columns.
    compare : sequence of (name, CalibrationResult)
        Other methods to put beside it.
    nav_velocity : (t_s, v_enu_m_s), optional
        Navigated velocity over a bag with the calibration applied.
    """
    name = str(calib.extra.get('method', 'calibration'))
    parts = [f'<h1>{html.escape(title)}</h1>',
             '<h2>Methods side by side</h2>',
             comparison_table([(name, calib), *compare], truth)]
    check = selfcheck_table(calib.extra)
    if check:
        parts += ['<h2>Self-check of the run</h2>', check]
    sections = [('Estimate convergence (3-sigma bands)', convergence_plot(calib.extra),
                 'no extra.history in the calibration file: convergence plot skipped'),
                ('Navigated velocity in the oscillation cycles (Kozlov Fig. 4 analogue)',
                 velocity_plot(calib.extra), 'no oscillation cycles in this calibration'),
                ('Stationary-window accelerations per SRT sequence', srt_plot(calib.extra),
                 'no SRT sequences in this calibration')]
    for _, other in compare:
        for head, fn in (('(compare) SRT', srt_plot), ('(compare) oscillation', velocity_plot)):
            img = fn(other.extra)
            if img:
                sections.append((head, img, ''))
    if nav_velocity is not None:
        t, v = nav_velocity
        fig, ax = plt.subplots(figsize=(8, 3))
        ax.plot(t, v)
        ax.set_xlabel('t [s]')
        ax.set_ylabel('navigated velocity error [m/s]')
        ax.legend(['E', 'N', 'U'])
        ax.set_title('from rest at the first stationary window, levelled on its '
                     'accelerometers; lever-arm velocity removed', fontsize=8)
        sections.append(('Navigated velocity over the bag (calibration applied)', _png(fig), ''))
    for head, img, note in sections:
        parts.append(f'<h2>{html.escape(head)}</h2>')
        parts.append(img if img else f'<p class="note">{html.escape(note)}</p>')
    style = ('<style>body{font-family:sans-serif}table{border-collapse:collapse;font-size:11px}'
             'td,th{border:1px solid #ccc;padding:2px 4px}.bad{background:#fcc}'
             '.fixed{color:#888;font-style:italic}'
             '.note{color:#777}</style>')
    return ('<!DOCTYPE html><html><head><meta charset="utf-8"><title>'
            + html.escape(title) + '</title>' + style + '</head><body>'
            + '\n'.join(parts) + '</body></html>')
