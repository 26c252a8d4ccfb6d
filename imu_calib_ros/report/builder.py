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

from ..core import parameters as registry  # noqa: E402
from ..core.param_table import is_fixed, srt_not_estimated  # noqa: E402,F401
from ..core.sensor_model import KEY_OF_FIELD  # noqa: E402
from ..core.units import ENGINEERING, UG_M_S2, element_unit  # noqa: E402

#: (SensorErrors field, label, factor to engineering units, CONTRACT 4 key)
ROWS = tuple((field, ENGINEERING[key][0], 1.0 / ENGINEERING[key][1], key)
             for field, key in KEY_OF_FIELD.items())


_srt_not_estimated = srt_not_estimated  # the name the tests knew


#: micro-g per m/s^2 (standard gravity)
UG_PER_M_S2 = 1.0 / UG_M_S2


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format='png', dpi=90, bbox_inches='tight')
    plt.close(fig)
    return ('<img alt="plot" src="data:image/png;base64,'
            + base64.b64encode(buf.getvalue()).decode('ascii') + '"/>')


def _entries(fld: str) -> tuple[tuple[int, ...], ...]:
    """The free entries of a SensorErrors field (45-vector order, the registry's)."""
    return registry.PARAMETER_OF_FIELD[fld].entries


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
    for fld, label, k, key in ROWS:
        if all(is_fixed(res, fld, key, idx) and not np.any(np.asarray(
                getattr(res.errors, fld))) for _, res in results for idx in _entries(fld)):
            continue  # held at zero by every method: the parameter blocks say so once
        for idx in _entries(fld):
            unit = element_unit(key, idx)
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
    """Stationary-window accelerations per SRT sequence: measured Delta a_H and residual.

    One tick per sequence (not per row: 70 row labels are unreadable), sequences shaded
    alternately, the rows of a sequence side by side within its band.
    """
    seqs = extra.get('srt', {}).get('sequences')
    if not seqs:
        return None
    meas, res, sig, centres, names, bands = [], [], [], [], [], []
    x0 = 0
    for s in seqs:
        n = len(s['rows'])
        meas += [m * UG_PER_M_S2 for m in s['delta_a_h_m_s2']]
        res += [r * UG_PER_M_S2 for r in s['residual_m_s2']]
        sig += [g * UG_PER_M_S2 for g in s['sigma_m_s2']]
        centres.append(x0 + (n - 1) / 2)
        names.append(str(s['label']).replace('srt:', ''))
        bands.append((x0 - 0.5, x0 + n - 0.5))
        x0 += n
    width = min(max(8.0, 0.16 * x0 + 2), 16.0)
    fig, ax = plt.subplots(2, 1, figsize=(width, 5.5), sharex=True)
    x = np.arange(x0)
    ax[0].bar(x, meas, color='tab:blue')
    ax[0].set_ylabel('measured Delta a_H [ug]')
    ax[0].set_title(f'SRT: horizontal acceleration change over each of {len(seqs)} sequences '
                    '(Savage eq. 1), before the correction', fontsize=10)
    ax[1].errorbar(x, res, yerr=3 * np.array(sig), fmt='o', ms=3, color='tab:red')
    ax[1].axhline(0, color='k', lw=0.5)
    ax[1].set_ylabel('residual after the fit [ug]\n(bars: 3 sigma)')
    for a in ax:  # ug values, not a matplotlib offset/scale factor hiding the unit
        a.ticklabel_format(axis='y', style='plain', useOffset=False)
        for k, (lo, hi) in enumerate(bands):
            if k % 2:
                a.axvspan(lo, hi, color='0.92', zorder=0)
    ax[1].set_xticks(centres, names, rotation=90 if len(seqs) > 16 else 0, fontsize=8)
    ax[1].set_xlabel('SRT sequence (Savage Table 1 id; seq:N = several sequences the dwells '
                     'did not separate)')
    ax[1].set_xlim(-0.5, x0 - 0.5)
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


def _element(group: str, i: int) -> str:
    """``'x'``, ``'xy'``: the entry a state of ``group`` is (the registry's orders); a joint
    zero offset (a general chain, not a registry group): its index."""
    if group not in registry.GROUP_OF_NAME:
        return f'#{i}'
    return registry.group(group).entry_name(i)


def _history_groups(h: dict[str, Any]) -> list[tuple[str, list[int], float, str]]:
    """(group, columns, SI per unit, unit) of a history's state labels, in state order."""
    from ..core.estimator.error_model import GROUP_INFO
    out: dict[str, list[int]] = {}
    for i, n in enumerate(h.get('names') or []):
        out.setdefault(str(n).split('[')[0], []).append(i)
    return [(g, cols, GROUP_INFO[g][2], GROUP_INFO[g][3]) for g, cols in out.items()
            if g in GROUP_INFO]


def convergence_plot(extra: dict[str, Any], truth_values: dict[str, float] | None = None
                     ) -> str | None:
    """Estimates against time with 3-sigma bands, one panel per state group, in
    engineering units (``extra.history``, recorded by the streaming estimator)."""
    h = extra.get('history')
    if not isinstance(h, dict) or not {'t_s', 'value', 'sigma', 'names'} <= set(h):
        return None
    t = np.asarray(h['t_s'], float)
    v = np.asarray(h['value'], float)
    s = np.asarray(h['sigma'], float)
    groups = _history_groups(h)
    if not groups or len(t) < 2:
        return None
    ncol = 3
    nrow = (len(groups) + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(13, 2.6 * nrow), squeeze=False)
    from ..core.param_table import fmt
    for k, (g, cols, si, unit) in enumerate(groups):
        ax = axes[k // ncol][k % ncol]
        for c_i, c in enumerate(cols):
            color = f'C{c_i % 10}'
            # each entry about its own final value: the entries of a group differ by far
            # more than their sigmas (a MEMS Kg: 5560 and -2045 ppm, sigma 20), so on one
            # absolute axis the bands vanish; the final value is in the legend
            end = v[-1, c]
            ax.plot(t, (v[:, c] - end) / si, color=color, lw=1,
                    label=f'{_element(g, c_i)} {fmt(float(end / si), 3)}')
            ax.fill_between(t, (v[:, c] - end - 3 * s[:, c]) / si,
                            (v[:, c] - end + 3 * s[:, c]) / si, color=color, alpha=0.15, lw=0)
            if truth_values and h['names'][c] in truth_values:
                ax.axhline((truth_values[h['names'][c]] - end) / si, color=color, ls='--',
                           lw=0.8)
        # the final 3-sigma bands set the scale; the prior's would flatten the end
        hi = 6 * np.max(s[-1, cols]) / si
        if np.isfinite(hi) and hi > 0:
            ax.set_ylim(-hi, hi)
        ax.axhline(0.0, color='k', lw=0.4)
        ax.set_title(f'{g} minus its final value [{unit}]', fontsize=9)
        ax.tick_params(labelsize=7)
        if len(cols) <= 9:
            ax.legend(fontsize=6, ncol=3, loc='upper right', framealpha=0.6)
    for k in range(len(groups), nrow * ncol):
        axes[k // ncol][k % ncol].axis('off')
    for a in axes[-1]:
        a.set_xlabel('t [s] from the alignment', fontsize=8)
    fig.suptitle('estimate minus its final value (legend: the final value) with its 3-sigma '
                 'band against time; dashed: truth minus the final value; y range +- 6 final '
                 'sigmas', fontsize=10)
    fig.tight_layout()
    return _png(fig)


def sigma_plot(extra: dict[str, Any]) -> str | None:
    """Each state's sigma over its initial sigma against time (log): what the plan taught
    the filter, and when."""
    h = extra.get('history')
    if not isinstance(h, dict) or not {'t_s', 'sigma', 'names'} <= set(h):
        return None
    t = np.asarray(h['t_s'], float)
    s = np.asarray(h['sigma'], float)
    groups = _history_groups(h)
    if not groups or len(t) < 2:
        return None
    from ..core.estimator.error_model import GROUP_INFO
    sides = (('gyroscope', lambda g: GROUP_INFO[g][4] == 'g'),
             ('accelerometer', lambda g: GROUP_INFO[g][4] == 'a'),
             ('fixture (lever arm, mounting, joint offsets)', lambda g: GROUP_INFO[g][4] == ''))
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4), sharey=True)
    for ax, (title, pick) in zip(axes, sides):
        k = 0
        for g, cols, _, _ in groups:
            if not pick(g):
                continue
            rel = s[:, cols] / np.where(s[0, cols] > 0, s[0, cols], 1.0)
            for j, c in enumerate(cols):
                ax.semilogy(t, rel[:, j], color=f'C{k % 10}', lw=1,
                            label=g if j == 0 else None)
            k += 1
        ax.set_title(title, fontsize=9)
        ax.set_xlabel('t [s]', fontsize=8)
        ax.tick_params(labelsize=7)
        if k:
            ax.legend(fontsize=6)
    axes[0].set_ylabel('sigma / initial sigma')
    fig.tight_layout()
    return _png(fig)


def nis_plot(extra: dict[str, Any]) -> str | None:
    """Mean NIS per degree of freedom of each history interval with its 99 % band."""
    from scipy.stats import chi2
    h = extra.get('history')
    nis = (h or {}).get('nis') if isinstance(h, dict) else None
    if not nis:
        return None
    assert isinstance(h, dict)
    t = np.asarray(h['t_s'], float)
    fig, axes = plt.subplots(1, len(nis), figsize=(6.5 * len(nis), 3), squeeze=False)
    for ax, (kind, d) in zip(axes[0], nis.items()):
        n = np.asarray(d['accepted'], float)
        ok = n > 0
        dof = 3 * n[ok]
        mean = np.asarray(d['sum'], float)[ok] / dof
        ax.fill_between(t[ok], chi2.ppf(0.005, dof) / dof, chi2.ppf(0.995, dof) / dof,
                        step='mid', color='tab:green', alpha=0.2, label='99 % band')
        ax.plot(t[ok], mean, 'o-', ms=3, lw=1, label='mean NIS / dof')
        gated = np.asarray(d['gated'], float)
        if gated.any():
            ax.plot(t[gated > 0], np.full(int((gated > 0).sum()), ax.get_ylim()[1]), 'rv',
                    label='gated updates')
        ax.axhline(1.0, color='k', lw=0.5)
        ax.set_title(f'{kind} updates ({int(n.sum())} accepted, {int(gated.sum())} gated)',
                     fontsize=9)
        ax.set_xlabel('t [s]')
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel('NIS per dof')
    fig.tight_layout()
    return _png(fig)


def innovation_plot(extra: dict[str, Any]) -> str | None:
    """Normalised innovations (``y_i / sqrt(S_ii)``, ENU components) against time: top, the
    interval mean as a z-score (``mean sqrt(n)``, N(0, 1) for a consistent filter) with the
    +-3 band; bottom, the interval rms against 1. Files before session 6 have no innovations
    in their history: None."""
    h = extra.get('history')
    nis = (h or {}).get('nis') if isinstance(h, dict) else None
    kinds = {k: d for k, d in (nis or {}).items() if 'innovation_mean' in d}
    if not kinds:
        return None
    assert isinstance(h, dict)
    t = np.asarray(h['t_s'], float)
    fig, axes = plt.subplots(2, len(kinds), figsize=(6.5 * len(kinds), 4.6), squeeze=False,
                             sharex=True)
    for c, (kind, d) in enumerate(kinds.items()):
        n = np.asarray(d['accepted'], float)
        ok = n > 0
        z = np.asarray(d['innovation_mean'], float)[ok] * np.sqrt(n[ok])[:, None]
        rms = np.asarray(d['innovation_rms'], float)[ok]
        top, bot = axes[0][c], axes[1][c]
        top.axhspan(-3.0, 3.0, color='tab:green', alpha=0.15, label='+-3 (99.7 %)')
        for i, (name, color) in enumerate(zip('ENU', ('tab:red', 'tab:green', 'tab:blue'))):
            top.plot(t[ok], z[:, i], '.-', ms=3, lw=0.7, color=color, label=name)
            bot.plot(t[ok], rms[:, i], '.-', ms=3, lw=0.7, color=color, label=name)
        bot.axhline(1.0, color='k', lw=0.6)
        beyond = float(np.mean(np.abs(z) > 3.0)) if z.size else 0.0
        top.set_title(f'{kind}: interval mean as z-score ({100 * beyond:.0f} % of points '
                      'beyond 3; 0.3 % expected)', fontsize=9)
        bot.set_title(f'{kind}: interval rms (1 for a consistent filter)', fontsize=9)
        bot.set_xlabel('t [s]')
        top.legend(fontsize=7, ncol=4)
    axes[0][0].set_ylabel('mean x sqrt(n)')
    axes[1][0].set_ylabel('rms of y / sqrt(S)')
    fig.tight_layout()
    return _png(fig)


def joint_plot(bag: Any) -> str | None:
    """Joint angles against time with the stationary windows (the plan's dwells) shaded."""
    if bag is None or len(bag.t_joint_s) < 2:
        return None
    fig, ax = plt.subplots(figsize=(13, 3))
    for k, name in enumerate(bag.joint_names):
        ax.plot(bag.t_joint_s, bag.q_deg[:, k], lw=1, label=name)
    for k, (a, b) in enumerate(bag.windows_s):
        ax.axvspan(a, b, color='tab:green', alpha=0.15, lw=0,
                   label='stationary window' if k == 0 else None)
    ax.set_xlabel('t [s] from the first IMU sample')
    ax.set_ylabel('joint angle [deg]')
    ax.legend(fontsize=7, ncol=len(bag.joint_names) + 1, loc='upper left')
    ax.set_title(f'{len(bag.windows_s)} stationary windows, {bag.segments} motion segments',
                 fontsize=9)
    return _png(fig)


def allan_plot(bag: Any, noise: dict[str, Any] | None) -> str | None:
    """Allan deviation of each axis from the stationary windows (dots) with its IEEE 952 fit
    (lines; the same fit as ``imu-calib noise``), and the white-noise line of the density the
    run used (``sigma(tau) = N / sqrt(tau)``, dashed)."""
    res = getattr(bag, 'allan', None)
    if res is None:
        return None
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.8))
    specs = ((axes[0], 0, 1.0 / DEG_H, 'deg/h', 'gyro_noise_rad_s_rt_hz', 'gyroscopes',
              'gyro', 60.0 * 180.0 / np.pi, 'deg/sqrt(h)', 1.0 / DEG_H, 'deg/h'),
             (axes[1], 3, UG_PER_M_S2, 'ug', 'accel_noise_m_s2_rt_hz', 'accelerometers',
              'accel', UG_PER_M_S2, 'ug/sqrt(Hz)', UG_PER_M_S2, 'ug'))
    for ax, col, k, unit, key, title, sensor, kn, un, kb, ub in specs:
        for a, color in enumerate(('tab:red', 'tab:green', 'tab:blue')):
            f = res.fits[col + a]
            ax.loglog(f.tau_s, f.adev * k, 'o', ms=3, color=color, label='xyz'[a])
            ax.loglog(f.tau_s, f.model_adev * k, '-', lw=0.8, color=color)
        tau = res.fits[col].tau_s
        N = (noise or {}).get(key)
        if N:
            # the Allan deviation of white rate noise of density N [unit/sqrt(Hz)] is
            # N / sqrt(tau) (IEEE Std 952, C.1)
            ax.loglog(tau, N * k / np.sqrt(tau), 'k--', lw=1,
                      label=f'white noise used: N {N * kn:.3g} {un}')
        fitted = [f'N {res.value(sensor, "N") * kn:.3g} {un}']
        b = res.value(sensor, 'B')
        fitted.append(f'B {b * kb:.3g} {ub}' if b > 0 else
                      f'B < {res.bound(sensor, "B") * kb:.3g} {ub} (not shown)')
        ax.set_xlabel('tau [s]')
        ax.set_ylabel(f'Allan deviation [{unit}]')
        ax.set_title(f'{title}: fit ' + ', '.join(fitted), fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(True, which='both', lw=0.3)
    c = res.curve
    fig.suptitle(f'{res.source}, {c.duration_s:.0f} s at rest: measured (dots), IEEE 952 fit '
                 '(lines, as imu-calib noise), white noise the run used (dashed)', fontsize=9)
    fig.tight_layout()
    return _png(fig)


def _sparse_symlog_ticks(ax: Any, linthresh: float) -> None:
    """At most about seven labelled ticks on a symlog axis: 0 and every k-th decade on each
    side (matplotlib labels every decade, unreadable over 10 decades)."""
    lo, hi = ax.get_ylim()
    top = max(abs(lo), abs(hi), linthresh * 10)
    decades = np.arange(np.log10(linthresh), np.ceil(np.log10(top)) + 1)
    step = max(1, int(np.ceil(len(decades) / 3)))
    pos = 10.0 ** decades[::-1][::step]
    ticks = sorted([0.0, *[p for p in pos if p <= hi], *[-p for p in pos if -p >= lo]])
    ax.set_yticks(ticks)


def nav_plot(bag: Any) -> str | None:
    """Navigated horizontal velocity over the bag: no calibration, the estimate, others."""
    nav = getattr(bag, 'nav', None)
    if not nav:
        return None
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4), sharex=True)
    env = getattr(bag, 'envelope', None)
    for k, (name, (t, v)) in enumerate(nav.items()):
        for i, ax in enumerate(axes):
            ax.plot(t, v[:, i], lw=1, color=f'C{k}', label=name)
            if env is not None and name == 'this calibration':
                # what this calibration's sigmas allow: the spread of navigations with
                # calibrations drawn from them, about zero (the error it leaves should be in it)
                te, sd, draws = env
                ax.fill_between(te, -3 * sd[:, i], 3 * sd[:, i],
                                color=f'C{k}', alpha=0.2, lw=0,
                                label=f'3-sigma envelope ({draws} draws)' if i == 0 else None)
    for i, ax in enumerate(axes):
        ax.set_title(f'velocity error {"ENU"[i]}', fontsize=9)
        ax.set_xlabel('t [s] from the first stationary window')
        ax.set_yscale('symlog', linthresh=1e-3)
        _sparse_symlog_ticks(ax, 1e-3)
    axes[0].set_ylabel('[m/s] (symlog)')
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    return _png(fig)


DEG_H = np.pi / 180.0 / 3600.0


def _esc(x: Any) -> str:
    return html.escape(str(x))


def _kernels(est: dict[str, Any]) -> str:
    """``'; sampling kernels gyro 0.98 +- 0.16, accel 1.01 +- 0.09 (0 interval means, 1 point
    samples)'`` when they were states, else ''."""
    parts = []
    for side in ('gyro', 'accel'):
        k, sd = est.get(f'{side}_sample_kernel'), est.get(f'{side}_sample_kernel_sigma')
        if k is not None and sd:
            parts.append(f'{side} {k:.2f} +- {sd[0]:.2f}')
    if not parts:
        return ''
    return f'; sampling kernels {", ".join(parts)} (0 interval means, 1 point samples)'


def header_html(calib: Any, calib_path: str | None, fixture: Any, bag: Any,
                generated: str) -> str:
    """The document's header: what was calibrated, from what, with what, by what."""
    from .. import __version__
    ex = calib.extra
    est = ex.get('estimator') or {}
    method = ex.get('method', 'ekf' if est else 'unknown')
    rows: list[tuple[str, str]] = [('unit (frame_id)', calib.frame_id),
                                   ('calibration file', calib_path or '-'),
                                   ('method', str(method))]
    if bag is not None:
        rows += list(bag.summary().items())
    elif (ex.get('provenance') or {}).get('bag_reader', {}).get('bag'):
        rows.append(('bag', ex['provenance']['bag_reader']['bag'] + ' (not read: no --bag)'))
    if fixture is not None:
        joints = ', '.join(f'{j.name} {np.round(np.asarray(j.axis, float), 3).tolist()}'
                           for j in fixture.joints)
        rows.append(('fixture', f'{fixture.source or "-"}: joints (outermost first) {joints}; '
                                f'latitude {fixture.site.latitude_deg:.4f} deg, height '
                                f'{fixture.site.height_m:g} m'))
    cs = est.get('coarse_start')
    if cs:
        rows.append(('noise used (measured)',
                     f'gyro {cs["gyro_noise_rad_s_rt_hz"] / DEG_H / 60:.3g} deg/sqrt(h) '
                     f'({cs["gyro_noise_rad_s_rt_hz"] / DEG_H:.3g} deg/h/sqrt(Hz)), accel '
                     f'{cs["accel_noise_m_s2_rt_hz"] * UG_PER_M_S2:.3g} ug/sqrt(Hz), from '
                     f'{cs.get("static_windows", "?")} stationary windows'))
    elif ex.get('srt', {}).get('noise'):
        rows.append(('noise used', ', '.join(f'{k} {v:.3g}' for k, v in
                                             ex['srt']['noise'].items()
                                             if isinstance(v, (int, float)))))
    if est.get('estimated_groups'):
        rows.append(('estimator', f'states: {", ".join(est["estimated_groups"])}; encoder '
                                  'attitude aiding '
                                  f'{"on" if est.get("attitude_aiding") else "off"}'
                                  f'; time offset {1e3 * est.get("time_offset_s", 0.0):.3g} ms'
                                  f'{_kernels(est)}'))
    if isinstance(est.get('settings_changed'), dict):
        ch = est['settings_changed']
        listed = ', '.join(f'{k} {v}' for k, v in sorted(ch.items()))
        rows.append(('estimator settings', f'{listed} (the rest the defaults)' if ch
                     else 'the defaults (config/estimator.yaml)'))
    h = ex.get('history')
    if isinstance(h, dict) and h.get('t_s'):
        rows.append(('run', f'{h["t_s"][-1]:.1f} s filtered; history of {len(h["t_s"])} '
                            f'points every {h.get("period_s", 0):g} s or more'))
    rows += [('software', f'imu_calib_ros {__version__}'), ('report generated', generated)]
    body = ''.join(f'<tr><th>{_esc(k)}</th><td>{_esc(v)}</td></tr>' for k, v in rows)
    return f'<table class="header">{body}</table>'


def within_3_sigma(calib: Any, truth: Any) -> tuple[int, int]:
    """(estimated entries within 3 sigma of the truth, estimated entries compared)."""
    from ..core.param_table import blocks
    tb = {b.key: b for b in blocks(calib, truth.tracked_truth())}
    n_in = n = 0
    for b in blocks(calib):
        for idx in b.entries():
            if b.fixed[idx] or not b.sigma[idx] > 0:
                continue
            n += 1
            n_in += int(abs(b.value[idx] - tb[b.key].value[idx]) <= 3 * b.sigma[idx])
    return n_in, n


def selfcheck_table(extra: dict[str, Any]) -> str | None:
    """Every check of the run's self-check (``provenance.self_check``, issue 17) with its
    figure and limit, failed rows highlighted, or None."""
    v = (extra.get('provenance', {}) or {}).get('self_check')
    if not isinstance(v, dict):
        return None
    rows = ['<tr><th>check</th><th>value</th><th>limit</th><th>reading</th></tr>']
    for name, c in (v.get('checks') or {}).items():
        cls = '' if c.get('passed') else ' class="bad"'
        val, lim = (f'{x:.4g}' if isinstance(x, (int, float)) else '-'
                    for x in (c.get('value'), c.get('limit')))
        reading = 'passed' if c.get('passed') else str(c.get('text', ''))
        rows.append(f'<tr{cls}><td>{_esc(name)}</td><td>{val}</td><td>{lim}</td>'
                    f'<td style="text-align:left">{_esc(reading)}</td></tr>')
    return '<table>' + ''.join(rows) + '</table>'


CHECK_NAMES = {
    'gate': 'gated measurement updates',
    'input.rejected': 'fraction of IMU samples rejected',
    'input.lost': 'fraction of the recording not used',
    'windows.chi2': 'stationary-window residuals chi2/dof',
    'windows.worst': 'largest stationary-window residual [sigma]',
    'plausible': 'largest sensor error [raw-unit sigmas]',
}


def _summary_tail(summary: str) -> str:
    """The self-check summary after the headline's own "self-check PASSED/FAILED": its
    repeated opening ("self-check passed", "self-check failed:") dropped."""
    for lead in ('self-check passed', 'self-check failed'):
        if summary.lower().startswith(lead):
            summary = summary[len(lead):].lstrip(': ')
            break
    if not summary:
        return ''
    return f' {summary}' if summary.startswith('(') else f': {summary}'


def verdict_html(calib: Any, truth: Any | None) -> str:
    """The verdict block: self-check, health, NIS, divergence and restarts, rejected input,
    and with a truth the count within 3 sigma."""
    ex = calib.extra
    v = (ex.get('provenance', {}) or {}).get('self_check')
    health = (ex.get('estimator') or {}).get('health') or {}
    items = []
    if isinstance(v, dict):
        ok = bool(v.get('passed'))
        word = 'PASSED' if ok else ('FAILED (written with --force)' if v.get('forced')
                                    else 'FAILED')
        head = (f'<p class="verdict {"ok" if ok else "bad"}">Verdict: self-check {word}'
                f'{_esc(_summary_tail(str(v.get("summary", ""))))}</p>')
        checks = v.get('checks') or {}
        for name in ('nis.velocity', 'nis.attitude'):
            c = checks.get(name)
            if c:
                # the check bounds the upper tail; far below its band the stated noise is
                # pessimistic (the selfcheck's text says so): not "consistent"
                low = 'below its band' in str(c.get('text', ''))
                reading = ('TOO LARGE' if not c['passed'] else
                           'below its 99 % band: the stated measurement noise is '
                           'pessimistic' if low else 'consistent')
                items.append(f'{name.split(".")[1]} NIS per dof {c["value"]:.3g} '
                             f'(bound {c["limit"]:.3g}): {reading}')
        for name, what in (('restarts', 'divergence restarts'),
                           ('realignments', 're-alignments')):
            c = checks.get(name)
            if c:
                items.append(f'{what}: {int(c["value"])}')
        for name in ('gate', 'input.rejected', 'input.lost', 'windows.chi2', 'windows.worst',
                     'plausible'):
            c = checks.get(name)
            if not c:
                continue
            if c['passed']:  # the checks' texts describe a failure; say what passed
                lim = c.get('limit')
                items.append(f'{CHECK_NAMES.get(name, name)}: {c["value"]:.3g} (limit '
                             f'{lim if lim is None else format(lim, ".3g")}): passed')
            else:
                items.append('FAILED: ' + str(c['text']))
    else:
        head = ('<p class="verdict note">No self-check in this file: only EKF runs are '
                f'self-checked (method: {_esc(ex.get("method", "unknown"))}).</p>')
    if health:
        items.append(f'filter health {health.get("status", "?")} ({health.get("message", "")}); '
                     f'diverged: {"yes" if health.get("diverged") else "no"}')
        reasons = {k: health[k] for k in ('imu_out_of_order', 'imu_non_finite',
                                          'joint_out_of_order', 'joint_non_finite',
                                          'joint_missing_names', 'imu_dropped_at_gap',
                                          'gaps', 'gaps_reinitialised')
                   if health.get(k)}
        by_reason = health.get('rejected')
        if isinstance(by_reason, dict):  # the input guard's own split (files since session 6)
            for k in ('imu_out_of_order', 'imu_non_finite', 'joint_out_of_order',
                      'joint_non_finite', 'joint_missing_names'):
                reasons.pop(k, None)
            reasons.update({f'rejected for {k}': int(n) for k, n in sorted(by_reason.items())
                            if int(n)})
        # an older file keeps the guard's total but splits only these reasons; say the rest
        other = 0 if isinstance(by_reason, dict) else int(health.get('rejected_total', 0)) - sum(
            int(health.get(k, 0)) for k in ('imu_out_of_order', 'imu_non_finite',
                                            'joint_out_of_order', 'joint_non_finite',
                                            'joint_missing_names'))
        if other > 0:
            reasons['other input-guard rejections (frame_id, all_zero, saturated, '
                    'accel_magnitude, units, after a divergence; not split in the file)'] = other
        items.append('rejected or lost input: ' + (', '.join(f'{k} {n}' for k, n in
                                                            reasons.items()) or 'none')
                     + f' (of {health.get("imu_samples", "?")} IMU samples)')
    if truth is not None:
        n_in, n = within_3_sigma(calib, truth)
        items.append(f'against the truth: {n_in} of {n} estimated entries within 3 sigma '
                     f'({100 * n_in / max(n, 1):.0f} %; 99.7 % expected)')
    return head + '<ul>' + ''.join(f'<li>{_esc(i)}</li>' for i in items) + '</ul>'


def blocks_html(calib: Any, truth: Any | None) -> str:
    """Every parameter as a labelled vector or 3x3 matrix: value +- sigma unit per entry,
    significance |value|/sigma, with a truth the error in sigmas; fixed entries apart."""
    from ..core.param_table import MATRIX_NOTES, blocks, cell_text, folded_line, matrix_title
    tb = {b.key: b for b in blocks(calib, truth.tracked_truth())} if truth is not None else {}
    out = ['<div class="blocks">']
    bl = blocks(calib)
    for b in bl:
        if b.folded:
            continue
        z = b.significance()

        def cell(idx: tuple[int, ...]) -> str:
            if b.structural[idx]:
                return '<td class="fixed">-</td>'
            if b.fixed[idx]:
                return (f'<td class="fixed">{_esc(cell_text(b, idx, "&plusmn;"))}'
                        f'<br><small>assumed, sigma {b.sigma[idx]:.2g}</small></td>')
            txt = cell_text(b, idx, '±')
            extra = f'<br><small>|v|/&sigma; {z[idx]:.1f}'
            cls = ''
            if b.key in tb:
                e = (b.value[idx] - tb[b.key].value[idx]) / b.sigma[idx]
                extra += f'; err {e:+.1f}&sigma;'
                cls = ' class="bad"' if abs(e) > 3 else ''
            return f'<td{cls}>{_esc(txt)}{extra}</small></td>'

        title = matrix_title(b) if b.is_matrix else f'{b.label} [{b.unit_text}]'
        note = MATRIX_NOTES.get(b.key, '')
        if b.is_matrix:
            rows = ['<tr><th></th>' + ''.join(f'<th>{a}</th>' for a in 'xyz') + '</tr>']
            for i in range(3):
                rows.append(f'<tr><th>{"xyz"[i]}</th>' + ''.join(cell((i, j)) for j in range(3))
                            + '</tr>')
        else:
            rows = ['<tr>' + ''.join(f'<th>{a}</th>' for a in 'xyz') + '</tr>',
                    '<tr>' + ''.join(cell((i,)) for i in range(3)) + '</tr>']
        state = ' (all fixed)' if b.all_fixed else ''
        out.append(f'<div class="block"><h3>{_esc(title)}{state}</h3>'
                   + (f'<p class="note">{_esc(note)}</p>' if note else '')
                   + '<table>' + ''.join(rows) + '</table></div>')
    out.append('</div>')
    folded = [b for b in bl if b.folded]
    if folded:
        out.append(f'<p class="fixedline">{_esc(folded_line(folded))}</p>')
    return ''.join(out)


def change_table(calib: Any, others: Sequence[tuple[str, Any]]) -> str | None:
    """Change of every estimated entry from each other calibration to this one, with the
    combined sigma (two independent calibrations of the same unit)."""
    from ..core.param_table import blocks, fmt
    rows = []
    for name, other in others:
        if other.frame_id != calib.frame_id:
            continue
        ob = {b.key: b for b in blocks(other)}
        for b in blocks(calib):
            o = ob[b.key]
            for idx in b.entries():
                if b.fixed[idx] or o.fixed[idx]:
                    continue
                d = b.value[idx] - o.value[idx]
                sc = float(np.hypot(b.sigma[idx], o.sigma[idx]))
                z = d / sc if sc > 0 else float('nan')
                cls = ' class="bad"' if abs(z) > 3 else ''
                rows.append(f'<tr><td>{_esc(name)}</td><td>{_esc(b.label)}[{b.name_of(idx)}]'
                            f'</td><td>{_esc(b.units[idx])}</td><td>{fmt(float(o.value[idx]))}'
                            f'</td><td>{fmt(float(b.value[idx]))}</td><td>{fmt(float(d))}</td>'
                            f'<td>{fmt(sc, 2)}</td><td{cls}>{z:+.1f}</td></tr>')
    if not rows:
        return None
    head = ('<tr><th>other</th><th>parameter</th><th>unit</th><th>other value</th>'
            '<th>this value</th><th>change</th><th>combined &sigma;</th>'
            '<th>change/&sigma;</th></tr>')
    return '<table>' + head + ''.join(rows) + '</table>'


STYLE = ('<style>body{font-family:sans-serif;max-width:1250px;margin:auto;padding:0 12px}'
         'table{border-collapse:collapse;font-size:12px}'
         'td,th{border:1px solid #ccc;padding:2px 5px;text-align:right}'
         'table.header th,table.header td{text-align:left}'
         '.bad{background:#fcc}.fixed{color:#888;font-style:italic}'
         '.note{color:#666;font-size:12px}.verdict{font-size:16px;font-weight:bold;padding:6px}'
         '.verdict.ok{background:#dfd}.verdict.bad{background:#fcc}'
         '.blocks{display:flex;flex-wrap:wrap;gap:14px}.block h3{font-size:13px;margin:6px 0}'
         '.block .note{max-width:420px}.fixedline{color:#666;font-style:italic}'
         'img{max-width:100%}'
         '.reading{color:#333;font-size:13px;max-width:1000px}</style>')

#: what a reader learns from each section (printed under its plot)
READING = {
    'convergence': 'Each panel is one group of states: the line is the estimate minus its '
                   'final value (in the legend), the band its 3-sigma interval, the dashed '
                   'line (with --truth) where the truth lies. A band that narrows when the '
                   'plan excites the parameter and an estimate that stays inside its later '
                   'bands is a filter that learned from the data; a band that never narrows '
                   'marks a parameter this plan does not determine.',
    'sigma': 'Sigma over its initial value, per state: the steps show which part of the plan '
             'determined which parameter; states still near 1 were not observable.',
    'nis': 'The normalised innovation squared per interval against its 99 % band: points '
           'above the band mean the filter was more surprised than its covariance says '
           '(a model or noise error), points well below a pessimistic measurement noise.',
    'innovations': 'Each component of the innovations divided by its predicted sigma: the '
                   'interval means should scatter inside +-3 around 0 (a run of points on one '
                   'side is a bias the model lacks, e.g. a wrong lever arm or latency) and '
                   'the rms should sit near 1 (above: optimistic noise, below: pessimistic).',
    'joints': 'The fixture motion as recorded, with the stationary windows the estimator and '
              'the SRT use: check that the plan ran as intended.',
    'allan': 'The noise of the unit at rest, with the IEEE 952 terms fitted as imu-calib noise '
             'fits them (N white noise, B bias instability where the windows are long enough '
             'to show it): the white-noise part (slope -1/2) should lie on the dashed line of '
             'the density the run assumed; a curve above it means the sigmas of this '
             'calibration are optimistic.',
    'nav': 'Free-inertial velocity error from rest with each calibration applied: the better '
           'the calibration, the slower the drift (no calibration drifts fastest). The band '
           'is the error this calibration\'s sigmas allow (+-3 x the rms spread of '
           'navigations with calibrations drawn from them): its own curve should stay inside '
           '(outside: errors the sigmas do not cover, or the heading and noise the band '
           'leaves out); a curve of another calibration outside it differs by more than this '
           'one claims to know.',
    'srt': 'Savage\'s SRT: the measured horizontal acceleration change of each sequence and '
           'what the fit leaves; residuals inside their 3-sigma bars mean the error model '
           'explains the data.',
    'oscillation': 'Kozlov & Kapralov\'s oscillation cycles: navigated velocity per cycle.',
}


def build_report(calib: Any, truth: Any | None = None,
                 compare: Sequence[tuple[str, Any]] = (), title: str = 'IMU calibration',
                 nav_velocity: tuple[np.ndarray, np.ndarray] | None = None, *,
                 calib_path: str | None = None, fixture: Any = None, bag: Any = None,
                 generated: str | None = None, figures: list[Any] | None = None) -> str:
    """The HTML page as a string.

    Parameters
    ----------
    calib : CalibrationResult
        The main result; ``extra`` may carry ``history``, ``provenance.self_check``,
        ``estimator``, ``srt`` and ``oscillation``.
    truth : CalibrationResult, optional
        Simulator truth: error in sigmas per entry, count within 3 sigma.
    compare : sequence of (name, CalibrationResult)
        Other calibrations: side by side and the change from each.
    nav_velocity : (t_s, v_enu_m_s), optional
        Navigated velocity error with the calibration applied (when no ``bag``).
    bag : :class:`~.bag_facts.BagFacts`, optional
        The bag: header figures, joint timeline, Allan deviation, navigated velocities.

    Sections the calibration has no data for are left out; the page says once which.
    """
    import datetime
    generated = generated or datetime.datetime.now().astimezone().isoformat(timespec='seconds')
    if bag is None and nav_velocity is not None:
        from .bag_facts import BagFacts
        bag = BagFacts('', '', 0.0, 0, 0.0, (), np.zeros(0), np.zeros((0, 0)), [],
                       nav={'this calibration': nav_velocity})
    ex = calib.extra
    # an EKF file names no method (the header says ekf from its estimator key): the same here
    name = str(ex.get('method') or ('ekf' if ex.get('estimator') else 'this calibration'))
    parts = [f'<h1>{_esc(title)}</h1>',
             header_html(calib, calib_path, fixture, bag if bag and bag.path else None,
                         generated),
             '<h2>Verdict</h2>', verdict_html(calib, truth)]
    checks = selfcheck_table(ex)
    if checks:
        parts += ['<h3>Self-check of the run</h3>', checks]
    parts += ['<h2>Parameters</h2>',
              '<p class="note">value &plusmn; one sigma in engineering units per entry; '
              '|v|/&sigma;: significance of the value; italic grey: not estimated (held at '
              'its assumed value with its assumed sigma).</p>',
              blocks_html(calib, truth)]
    truth_values = None
    if truth is not None and isinstance(ex.get('history'), dict):
        truth_values = _truth_by_label(truth, ex['history'].get('names') or [])
    noise = (ex.get('estimator') or {}).get('coarse_start')
    missing: list[str] = []
    plots = [('Convergence of the estimates', 'convergence',
              convergence_plot(ex, truth_values), 'no estimate history (not an EKF run)'),
             ('What the data determined', 'sigma', sigma_plot(ex), None),
             ('Innovation consistency (NIS) against time', 'nis', nis_plot(ex), None),
             ('Innovations against time', 'innovations', innovation_plot(ex), None),
             ('Fixture motion and plan segments', 'joints', joint_plot(bag),
              'no joint timeline (give --bag and --fixture)'),
             ('Noise: Allan deviation at rest', 'allan', allan_plot(bag, noise),
              'no Allan deviation (give --bag and --fixture)'),
             ('Navigated velocity over the bag', 'nav', nav_plot(bag),
              'no navigated velocity (give --bag and --fixture)'),
             ('SRT sequences', 'srt', srt_plot(ex), None),
             ('Oscillation cycles (Kozlov Fig. 4 analogue)', 'oscillation', velocity_plot(ex),
              None)]
    for other_name, other in compare:
        plots.append((f'SRT sequences of {other_name}', 'srt', srt_plot(other.extra), None))
    for head, key, img, why in plots:
        if img is None:
            if why:
                missing.append(why)
            continue
        if figures is not None:
            figures.append(head)
        parts += [f'<h2>{_esc(head)}</h2>', img, f'<p class="reading">{_esc(READING[key])}</p>']
    if compare:
        ch = change_table(calib, compare)
        if ch:
            parts += ['<h2>Change from the other calibrations of this unit</h2>',
                      '<p class="note">this minus the other, entries estimated in both; '
                      'combined sigma = sqrt(sigma1^2 + sigma2^2) (independent runs). Drift '
                      'beyond 3 combined sigmas is a change of the unit (or of the '
                      'set-up).</p>', ch]
    if compare or truth is not None:
        parts += ['<h2>Methods side by side' + (' and against the truth' if truth else '')
                  + '</h2>', comparison_table([(name, calib), *compare], truth)]
    if missing:
        parts.append('<p class="note">Not in this report: ' + _esc('; '.join(missing))
                     + '.</p>')
    return ('<!DOCTYPE html><html><head><meta charset="utf-8"><title>' + _esc(title)
            + '</title>' + STYLE + '</head><body>' + '\n'.join(parts) + '</body></html>')


def _truth_by_label(truth: Any, labels: Sequence[str]) -> dict[str, float]:
    """Truth values (SI) of the history's state labels that are sensor errors."""
    from ..core.estimator import error_model as em
    tg, ta = em.theta_from_errors(truth.tracked_truth())
    out: dict[str, float] = {}
    for lab in labels:
        g = lab.split('[')[0]
        i = int(lab.split('[')[1][:-1])
        if g not in registry.GROUP_OF_NAME or registry.GROUP_OF_NAME[g].key is None:
            continue  # an auxiliary state (time offset, sampling kernels): no truth here
        if g in em.GYRO_GROUPS:
            out[lab] = float(tg[em.gyro_cols(g)][i])
        elif g in em.ACCEL_GROUPS:
            out[lab] = float(ta[em.accel_cols(g)][i])
    return out
