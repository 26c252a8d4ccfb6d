"""Issue 12: the report and the replay summary as documents an IMU engineer can check: the
units of each entry, fixed parameters apart, the verdict, the sections and the plots."""
from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.estimator import CalibrationEstimator, EstimatorConfig
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from imu_calib_ros.core.param_table import blocks, format_text
from imu_calib_ros.core.plans import build_profile, load_plan
from imu_calib_ros.core.simulator import SimConfig, simulate


@pytest.fixture(scope='module')
def ekf(tmp_path_factory):
    """An EKF calibration of demo_short (nav grade) through its file, and the truth."""
    fx = load_fixture('three_axis')
    sim = simulate(fx, build_profile(load_plan('demo_short'), fx), load_grade('nav_grade'),
                   SimConfig(imu_rate_hz=100.0, seed=1))
    est = CalibrationEstimator(fx, None, EstimatorConfig())
    est.push_joint_batch(sim.joints)
    est.push_imu_batch(sim.imu)
    est.flush()
    from imu_calib_ros.core.estimator.selfcheck import with_verdict
    res = est.estimate()
    verdict = {'passed': True, 'summary': 'self-check passed (2 checks, false-alarm rate 1 %)',
               'checks': {'nis.velocity': {'passed': True, 'value': 1.0, 'limit': 1.06,
                                           'text': 'velocity NIS ...'},
                          'restarts': {'passed': True, 'value': 0.0, 'limit': 0.0,
                                       'text': 'restarted 0 time(s)'}}}
    res = dataclasses.replace(res, extra=with_verdict(res.extra, verdict))
    p = tmp_path_factory.mktemp('ekf') / 'calib.yaml'
    res.save(p)
    return CalibrationResult.load(p), sim.truth, p


def _imgs(page: str) -> int:
    return len(re.findall(r'src="data:image/png;base64,', page))


def _text(page: str) -> str:
    return re.sub(r'<[^>]+>', ' ', page)


def test_units_per_entry_ppm_on_the_diagonal_urad_off_it(ekf) -> None:
    calib, _, _ = ekf
    bl = {b.key: b for b in blocks(calib)}
    for key in ('gyroscope.scale_misalignment', 'accelerometer.scale_misalignment'):
        u = bl[key].units
        assert all(u[i, i] == 'ppm' for i in range(3))
        assert all(u[i, j] == 'urad' for i in range(3) for j in range(3) if i != j)
    assert bl['gyroscope.bias'].units.tolist() == ['deg/h'] * 3
    assert bl['accelerometer.size_effect'].structural.diagonal().all()
    text = format_text(calib)
    assert 'ppm|urad' not in text and 'ppm/urad' not in text
    # the Kg block: a header row x y z, then rows x, y, z with ppm on the diagonal only
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith('gyro Kg'))
    assert lines[k + 1].split() == ['x', 'y', 'z']
    for i, row in enumerate(lines[k + 2:k + 5]):
        cells = re.findall(r'(-?[\d.e+-]+ \+- [\d.e+-]+ (\w+))', row)
        assert row.split()[0] == 'xyz'[i] and len(cells) == 3, row
        assert [c[1] for c in cells] == ['ppm' if j == i else 'urad' for j in range(3)], row
    # vectors: the label, then one row in the same columns; no line wider than 90 columns
    k = next(i for i, line in enumerate(lines) if line.startswith('gyro bias [deg/h]'))
    assert len(re.findall(r'\+- [\d.e+-]+ deg/h', lines[k + 1])) == 3, lines[k + 1]
    assert max(map(len, lines[1:])) <= 90, max(lines[1:], key=len)


@pytest.mark.parametrize('x, sigma, text', [
    (0.003496, 0.082, '0.003'),     # digits under the noise: the line was 93 columns wide
    (-0.01366, 0.046, '-0.014'),
    (12.3123, 0.32, '12.31'),       # at most four significant digits, as before
    (-4e-05, 0.0012, '0.0000'),     # no '-0.0000'
    (1.5e-05, 2e-06, '1.500e-05'),  # outside the plain range: as fmt
])
def test_a_value_is_shown_no_finer_than_its_sigma(x: float, sigma: float, text: str) -> None:
    from imu_calib_ros.core.param_table import fmt_at_sigma
    assert fmt_at_sigma(x, sigma) == text


def test_fixed_parameters_are_never_shown_as_estimates() -> None:
    """An SRT run that could not separate its sequences holds most of Kg fixed: those
    entries say '(fixed)' and carry no sigma; the estimated diagonal keeps its +-."""
    from imu_calib_ros.core.sensor_model import SensorErrors
    e = SensorErrors.zeros()
    kg = np.diag([12e-6, 14e-6, -31e-6])
    e = dataclasses.replace(e, gyro_scale_misalignment=kg)
    s = dataclasses.replace(SensorErrors.zeros(), gyro_scale_misalignment=np.full((3, 3), 15e-6),
                            gyro_g_sensitivity_rad_s_per_m_s2=np.zeros((3, 3)))
    res = CalibrationResult(e, s, 'imu', fixed=('gyroscope.scale_misalignment',
                                                'gyroscope.g_sensitivity'),
                            extra={'srt': {'not_estimated': ['Kg_xy', 'Kg_xz', 'Kg_yz']}})
    text = format_text(res)
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith('gyro Kg'))
    rows = lines[k + 2:k + 5]
    # (the value to its sigma's second digit: 12, not 12.00)
    assert ' 12 +- 15 ppm' in rows[0] and rows[0].count('(fixed)') == 2
    assert all(r.count('+-') == 1 for r in rows), rows  # only the diagonal is estimated
    # G held at zero with zero sigma: one folded line, no block of zeros
    assert 'gyro G (assumed exactly zero)' in lines[-1]
    assert not any(line.startswith('gyro G [') for line in lines)


def test_report_sections_header_verdict_and_plots(ekf) -> None:
    from imu_calib_ros import __version__
    from imu_calib_ros.report import build_report
    calib, truth, path = ekf
    figures: list[str] = []
    page = build_report(calib, truth, calib_path=str(path), figures=figures)
    text = _text(page)
    for must in ('unit (frame_id)', calib.frame_id, str(path), f'imu_calib_ros {__version__}',
                 'report generated', 'noise used (measured)', 'encoder attitude aiding off'):
        assert must in text, must
    assert 'Verdict: self-check PASSED' in text
    n_in, n = map(int, re.search(r'(\d+) of (\d+) estimated entries within 3 sigma',
                                 text).groups())
    assert n >= 40 and n_in >= n - 2
    # the history gives four plots; without a bag the bag's sections are named once
    assert figures == ['Convergence of the estimates', 'What the data determined',
                       'Innovation consistency (NIS) against time', 'Innovations against time']
    assert _imgs(page) == 4
    assert page.count('Not in this report') == 1 and 'give --bag and --fixture' in page
    # each plot is followed by what a reader learns from it
    assert page.count('class="reading"') == 4
    # parameter blocks: Kg diagonal cells in ppm, off-diagonal in urad
    kg = page.split('<h3>gyro Kg</h3>')[1].split('</table>')[0]
    assert kg.count(' ppm') == 3 and kg.count(' urad') == 6


def test_a_failed_self_check_is_the_first_thing_the_page_says(ekf) -> None:
    from imu_calib_ros.core.estimator.selfcheck import with_verdict
    from imu_calib_ros.report import build_report
    calib, _, _ = ekf
    bad = {'passed': False, 'summary': 'self-check failed: velocity NIS per dof 3.2',
           'checks': {'nis.velocity': {'passed': False, 'value': 3.2, 'limit': 1.06,
                                       'text': 'velocity NIS per dof 3.2 over 1795 updates'},
                      'gate': {'passed': False, 'value': 40, 'limit': 1,
                               'text': '40 of 1795 measurement updates gated'}}}
    extra = dict(calib.extra)
    extra.pop('provenance')
    forced = dataclasses.replace(calib, extra=with_verdict(extra, bad, forced=True))
    page = build_report(forced)
    verdict = page.split('<h2>Verdict</h2>')[1].split('<h2>')[0]
    assert 'class="verdict bad"' in verdict
    assert 'self-check FAILED (written with --force)' in verdict
    assert 'TOO LARGE' in verdict and 'FAILED: 40 of 1795 measurement updates gated' in verdict
    assert page.index('Verdict') < page.index('<h2>Parameters')


def test_change_between_two_calibrations_uses_the_combined_sigma(ekf) -> None:
    from imu_calib_ros.report.builder import change_table
    calib, _, _ = ekf
    kg = np.array(calib.errors.gyro_scale_misalignment)
    kg[0, 0] += 5 * float(np.hypot(calib.sigma.gyro_scale_misalignment[0][0],
                                   calib.sigma.gyro_scale_misalignment[0][0]))
    old = dataclasses.replace(calib, errors=dataclasses.replace(calib.errors,
                                                                gyro_scale_misalignment=kg))
    table = change_table(calib, [('old', old)])
    row = next(r for r in table.split('<tr>') if 'gyro Kg[xx]' in r)
    assert 'class="bad">-5.0<' in row  # this minus old: -5 combined sigmas, flagged
    row = next(r for r in table.split('<tr>') if 'gyro Kg[yy]' in r)
    assert '>+0.0<' in row


def test_history_plots_and_pdf(ekf, tmp_path, capsys) -> None:
    """The CLI writes the HTML and, with --pdf, a PDF with a page per plot."""
    from imu_calib_ros.cli import main
    _, _, path = ekf
    out, pdf = tmp_path / 'r.html', tmp_path / 'r.pdf'
    assert main(['report', str(path), '--output', str(out), '--pdf', str(pdf)]) == 0
    data = pdf.read_bytes()
    assert data[:5] == b'%PDF-'
    pages = len(re.findall(rb'/Type\s*/Page[^s]', data))
    assert pages >= 1 + 3, pages  # text, then convergence, sigma, NIS


def test_replay_summary_is_the_param_table() -> None:
    """The replay summary is format_text (one layout code for the terminal and the report)."""
    from imu_calib_ros.cli.replay import _summary
    from imu_calib_ros.core.sensor_model import SensorErrors
    res = CalibrationResult.exact(SensorErrors.zeros())
    assert _summary(res) == format_text(res)


def _with_checks(calib, checks, summary, health=None, passed=True):
    from imu_calib_ros.core.estimator.selfcheck import with_verdict
    extra = dict(calib.extra)
    extra.pop('provenance')
    if health is not None:
        extra['estimator'] = {**extra['estimator'],
                              'health': {**extra['estimator']['health'], **health}}
    return dataclasses.replace(calib, extra=with_verdict(
        extra, {'passed': passed, 'summary': summary, 'checks': checks}))


def test_verdict_says_each_thing_once_and_reads_a_low_nis_as_pessimistic(ekf) -> None:
    """The headline does not repeat "self-check passed"; an attitude NIS far below its band
    passes the (upper-tail) check but is not called consistent; guard rejections the file
    does not split by reason are still counted, never read as "none"."""
    from imu_calib_ros.report.builder import verdict_html
    calib, _, _ = ekf
    checks = {'nis.velocity': {'passed': True, 'value': 1.04, 'limit': 1.5,
                               'text': 'velocity NIS per dof 1.04 over 1795 updates'},
              'nis.attitude': {'passed': True, 'value': 0.188, 'limit': 1.5,
                               'text': 'attitude NIS per dof 0.188 over 1795 updates (below '
                                       'its band: pessimistic noise)'}}
    res = _with_checks(calib, checks, 'self-check passed (2 checks, false-alarm rate 1 %)',
                       {'rejected_total': 7, 'imu_non_finite': 2})
    text = _text(verdict_html(res, None))
    assert 'Verdict: self-check PASSED (2 checks, false-alarm rate 1 %)' in text
    assert text.lower().count('self-check passed') == 1
    assert 'velocity NIS per dof 1.04 (bound 1.5): consistent' in text
    assert 'attitude NIS per dof 0.188 (bound 1.5): below its 99 % band' in text
    assert 'imu_non_finite 2' in text and 'not split in the file) 5' in text
    assert 'rejected or lost input: none' not in text
    failed = _with_checks(calib, {}, 'self-check failed: velocity NIS per dof 3.2',
                          passed=False)
    text = _text(verdict_html(failed, None))
    assert 'Verdict: self-check FAILED: velocity NIS per dof 3.2' in text
    assert text.lower().count('self-check') == 1


def test_verdict_names_each_rejection_reason_the_file_keeps(ekf) -> None:
    """Files since session 6 keep the input guard's split (estimator.health.rejected): the
    verdict names each reason with its count and nothing is left 'not split'."""
    from imu_calib_ros.report.builder import verdict_html
    calib, _, _ = ekf
    res = _with_checks(calib, {}, 'self-check passed (0 checks, false-alarm rate 1 %)',
                       {'rejected_total': 7, 'imu_non_finite': 2,
                        'rejected': {'non_finite': 2, 'frame_id': 4, 'saturated': 1}})
    text = _text(verdict_html(res, None))
    assert 'rejected for frame_id 4' in text and 'rejected for saturated 1' in text
    assert 'rejected for non_finite 2' in text
    assert 'not split' not in text and 'imu_non_finite' not in text  # counted once


def test_methods_table_names_the_ekf_column(ekf) -> None:
    from imu_calib_ros.report import build_report
    calib, truth, _ = ekf
    page = build_report(calib, truth, [('old', calib)])
    table = page.split('<h2>Methods side by side')[1]
    assert '<th>ekf</th>' in table and '<th>old</th>' in table
    assert 'this calibration' not in table


def test_convergence_panels_are_about_the_final_value(ekf, monkeypatch) -> None:
    """Entries of one group differ by far more than their sigmas (a MEMS Kg: thousands of
    ppm, sigma 20): each line is the estimate minus its final value, so every band is
    visible on one axis, the final value in the legend."""
    from imu_calib_ros.core.param_table import fmt
    from imu_calib_ros.report import builder
    calib, _, _ = ekf
    figs = []
    monkeypatch.setattr(builder, '_png', lambda fig: figs.append(fig) or 'img')
    assert builder.convergence_plot(calib.extra) == 'img'
    kg = calib.errors.gyro_scale_misalignment
    axes = {a.get_title(): a for a in figs[0].axes if a.get_title()}
    ax = axes['gyro_scale minus its final value [ppm]']
    lines = [ln for ln in ax.get_lines() if len(ln.get_xdata()) > 2]
    assert len(lines) == 3
    for ln in lines:
        assert ln.get_ydata()[-1] == pytest.approx(0.0, abs=1e-9)
    lo, hi = ax.get_ylim()
    assert lo == pytest.approx(-hi) and hi < 100  # +-6 final sigmas (~0.3 ppm), not 50 ppm
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[0] == f'x {fmt(kg[0][0] * 1e6, 3)}'  # the final value, ppm


def _chromium(*args: str, tmp_path) -> bytes:
    import shutil
    import subprocess
    exe = shutil.which('chromium') or shutil.which('chromium-browser')
    if exe is None:
        pytest.skip('chromium not installed (no chromium on PATH): render check skipped')
    return subprocess.run(
        [exe, '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic',
         '--no-first-run', '--disable-background-networking', '--disable-component-update',
         '--disable-sync', '--hide-scrollbars',
         f'--user-data-dir={tmp_path / "chromium-profile"}', *args],
        check=True, timeout=120, capture_output=True).stdout


def test_full_report_rendered_in_chromium_has_every_section(ekf, tmp_path) -> None:
    """The README's report (bag, truth, compare) rendered by headless Chromium at a laptop
    width: the rendered page's text has the header, the verdict and every section, each
    plot an image that loaded, and nothing is listed as missing."""
    import html as html_mod
    from imu_calib_ros.cli import main
    calib, truth, path = ekf
    _chromium('--version', tmp_path=tmp_path)  # skip before simulating if absent
    bag, srt, tp = tmp_path / 'bag', tmp_path / 'srt.yaml', tmp_path / 'truth.yaml'
    assert main(['simulate', '--fixture', 'three_axis', '--plan', 'demo_short', '--imu',
                 'nav_grade', '--rate', '100', '--seed', '1', '--output', str(bag),
                 '--truth', str(tp)]) == 0
    assert main(['replay', str(bag), '--fixture', 'three_axis', '--method', 'srt',
                 '--output', str(srt), '--quiet']) == 0
    out = tmp_path / 'report.html'
    assert main(['report', str(path), '--truth', str(tp), '--compare', str(srt), '--bag',
                 str(bag), '--fixture', 'three_axis', '--output', str(out)]) == 0
    dom = _chromium('--dump-dom', out.as_uri(), tmp_path=tmp_path).decode()
    text = html_mod.unescape(re.sub(r'\s+', ' ', _text(dom.split('<body')[1])))
    for must in ('unit (frame_id)', 'content hash (sha256)', 'plan segments detected',
                 '17 stationary windows', 'fixture', 'three_axis.yaml', 'noise used (measured)',
                 'estimator', 'software', 'report generated', str(bag)):
        assert must in text, must
    assert re.search(r'content hash \(sha256\) [0-9a-f]{16}', text)
    assert 'Verdict: self-check PASSED' in text and 'estimated entries within 3 sigma' in text
    sections = ['Verdict', 'Parameters', 'Convergence of the estimates',
                'What the data determined', 'Innovation consistency (NIS) against time',
                'Innovations against time', 'Fixture motion and plan segments',
                'Noise: Allan deviation at rest',
                'Navigated velocity over the bag', 'SRT sequences of srt',
                'Change from the other calibrations of this unit',
                'Methods side by side and against the truth']
    heads = [html_mod.unescape(h) for h in re.findall(r'<h2>(.*?)</h2>', dom)]
    assert heads == sections, heads
    assert 'Not in this report' not in text
    assert _imgs(dom) == 8  # one per plot section (convergence ... SRT)
    for reading in ('Each panel is one group of states', 'Free-inertial velocity error',
                    'The noise of the unit at rest', 'check that the plan ran as intended'):
        assert reading in text, reading
    shot = tmp_path / 'r.png'
    _chromium(f'--screenshot={shot}', '--window-size=1366,6000', out.as_uri(),
              tmp_path=tmp_path)
    import matplotlib.image
    img = matplotlib.image.imread(shot)[..., :3]
    assert img.shape[:2] == (6000, 1366)
    coloured = (img.max(axis=2) - img.min(axis=2) > 0.2).sum()
    assert coloured > 50000, coloured  # the plots drew (not broken images)


def test_demo_table_is_laid_out_by_the_param_blocks(ekf) -> None:
    """The demo's estimate-vs-truth table uses the blocks of the replay summary and the
    report: the same labels and per-entry units, fixed entries never scored, and the
    report's count within 3 sigma."""
    from imu_calib_ros.demo import comparison_table
    from imu_calib_ros.report.builder import within_3_sigma
    calib, truth, _ = ekf
    text, within, total = comparison_table(calib, truth)
    kg = [line for line in text.splitlines() if line.startswith('gyro Kg[')]
    assert [line.split()[2] for line in kg] == ['ppm', 'urad', 'urad', 'ppm', 'urad', 'ppm']
    assert (within, total) == within_3_sigma(calib, truth)
    held = dataclasses.replace(calib, fixed=('accelerometer.quadratic',))
    text, within, total_held = comparison_table(held, truth)
    quad = [line for line in text.splitlines() if line.startswith('accel quad[')]
    assert len(quad) == 3 and all(line.endswith('fixed') for line in quad)
    assert total_held == total - 3


def test_allan_of_the_windows_is_the_noise_commands_fit() -> None:
    """The report's Allan panel is the fit of ``imu-calib noise`` on the stationary windows
    (one Allan implementation): white noise of known density in ten 5 s windows at 200 Hz
    reads back within the spread of 10,000 samples (a few per cent; 12 % allowed), and a
    window too short to use is left out."""
    import numpy as np

    from imu_calib_ros.report.bag_facts import windows_noise
    rng = np.random.default_rng(7)
    dt, n_g, n_a = 0.005, 1e-6, 5e-5
    x = rng.normal(0.0, 1.0, (20_000, 6)) / np.sqrt(dt)
    gyro, accel = x[:, :3] * n_g, x[:, 3:] * n_a + [0.0, 0.0, 9.8]
    wins = [(k * 2000, k * 2000 + 1000) for k in range(10)] + [(19_990, 19_995)]
    res = windows_noise(gyro, accel, dt, wins)
    assert res.source == '10 stationary windows'
    assert res.value('gyro', 'N') == pytest.approx(n_g, rel=0.12)
    assert res.value('accel', 'N') == pytest.approx(n_a, rel=0.12)
    assert windows_noise(gyro, accel, dt, [(0, 5)]) is None


def test_parameter_covariance_in_the_file_matches_its_sigmas(ekf) -> None:
    """extra.estimator.parameter_covariance (CONTRACT 4 order) has the file's sigmas on its
    diagonal (4 digits) and the filter's correlations off it (an SRT-like plan correlates
    an accelerometer's bias with its scale strongly)."""
    import numpy as np
    calib, _, _ = ekf
    cov = np.asarray(calib.extra['estimator']['parameter_covariance'], float)
    sd = calib.sigma.as_vector()
    assert cov.shape == (45, 45) and np.allclose(cov, cov.T, rtol=1e-3, atol=0)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), sd, rtol=1e-3)
    corr = cov / np.outer(sd, sd)
    off = np.abs(corr[~np.eye(45, dtype=bool)])
    assert off.max() > 0.3  # correlations kept, not a diagonal


def test_velocity_envelope_holds_this_calibration_not_the_raw_unit(ekf, tmp_path) -> None:
    """The navigated-velocity envelope (calibrations drawn from the file's covariance): the
    calibration's own velocity error stays inside +-3 x the spread for nearly all the bag
    (95 %: the band leaves out the heading error and the noise), the uncalibrated unit's
    leaves it. Nav grade, demo_short at 100 Hz, the file's own bag."""
    import argparse

    import numpy as np

    from imu_calib_ros.cli import main
    from imu_calib_ros.cli.report import _bag_facts
    calib, _, _ = ekf
    bag = tmp_path / 'bag'
    assert main(['simulate', '--fixture', 'three_axis', '--plan', 'demo_short', '--imu',
                 'nav_grade', '--rate', '100', '--seed', '1', '--output', str(bag)]) == 0
    args = argparse.Namespace(bag=str(bag), fixture='three_axis', envelope_draws=8,
                              imu_topic='/imu/data_raw', joint_topic='/joint_states')
    _, facts = _bag_facts(args, calib, [])
    t, sd, draws = facts.envelope
    assert draws == 8 and sd.shape == facts.nav['this calibration'][1].shape
    late = t > 20.0  # after the first rotations (the band starts at zero)
    own = np.abs(facts.nav['this calibration'][1][late]) <= 3 * sd[late] + 1e-4
    raw = np.abs(facts.nav['no calibration'][1][late]) <= 3 * sd[late] + 1e-4
    assert own.mean() > 0.95, own.mean(axis=0)
    assert raw.mean() < 0.8, raw.mean(axis=0)


def test_header_names_the_estimator_settings_that_differ_from_the_defaults(ekf) -> None:
    """The file records the settings that are not the shipped defaults (none for the plain
    command); the header says 'the defaults' or lists them."""
    import dataclasses as dc

    from imu_calib_ros.core.estimator import CalibrationEstimator, EstimatorConfig
    from imu_calib_ros.report.builder import header_html
    calib, _, _ = ekf
    assert calib.extra['estimator']['settings_changed'] == {}
    text = re.sub(r'\s+', ' ', _text(header_html(calib, None, None, None, 'now')))
    assert 'estimator settings the defaults' in text
    est = CalibrationEstimator(load_fixture('three_axis'), None,
                               EstimatorConfig(gate_probability=0.999, gate_action='reject'))
    changed = est._settings_changed()
    assert changed == {'gate_probability': 0.999, 'gate_action': 'reject'}
    ex = {**calib.extra, 'estimator': {**calib.extra['estimator'],
                                       'settings_changed': changed}}
    text = re.sub(r'\s+', ' ',
                  _text(header_html(dc.replace(calib, extra=ex), None, None, None, 'now')))
    assert 'gate_action reject, gate_probability 0.999 (the rest the defaults)' in text


def test_header_names_each_motion_segment_by_its_turns() -> None:
    """The plan segments in the header: each motion between two stationary windows as the
    joints it turned and by how much (deg), in order; past 24 segments, counted."""
    import numpy as np

    from imu_calib_ros.report.bag_facts import BagFacts
    t = np.linspace(0.0, 40.0, 401)
    q = np.zeros((401, 2))
    q[t >= 12, 1] = 90.0  # inner +90 between the first two windows
    q[t >= 25, 0] = -90.0  # outer -90 and inner back to 0 between the next two
    q[t >= 25, 1] = 0.0
    bag = BagFacts('b', 'h', 40.0, 4000, 100.0, ('outer', 'inner'), t, q,
                   [(2.0, 10.0), (14.0, 22.0), (28.0, 38.0)])
    assert bag.segment_moves() == ['inner +90', 'outer -90 inner -90']
    assert bag.summary()['plan segments detected'] == (
        '3 stationary windows, 2 motion segments between them: inner +90; outer -90 inner '
        '-90 (deg)')
    wins = [(2.0 + k, 2.5 + k) for k in range(30)]
    many = BagFacts('b', 'h', 40.0, 4000, 100.0, ('outer', 'inner'), t, q, wins)
    assert 'no net turn x' in many.summary()['plan segments detected']
