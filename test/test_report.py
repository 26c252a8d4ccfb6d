"""HTML report: self-contained, real PNG plots, methods-vs-truth table; renders in Chromium."""
import base64
import re
import shutil
import subprocess

import numpy as np
import pytest


@pytest.fixture(scope='module')
def srt_result():
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.methods import srt
    from imu_calib_ros.core.plans import build_profile, plan_from_dict
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fx = load_fixture('savage_2axis')
    plan = plan_from_dict({'name': 't', 'steps': [
        {'srt_sequence': {'id': i, 'dwell_s': 5, 'rotation_s': 6}} for i in ('1', '4', '7')]})
    sim = simulate(fx, build_profile(plan, fx), load_grade('nav_grade'),
                   SimConfig(imu_rate_hz=100, joint_rate_hz=50, seed=1))
    return srt.calibrate(sim.imu, sim.joints, fx, load_grade('nav_grade')), sim.truth


def test_report_has_plots_and_table(srt_result, tmp_path):
    from imu_calib_ros.core.calibration import CalibrationResult
    from imu_calib_ros.report import build_report
    calib, truth = srt_result
    p = tmp_path / 'c.yaml'
    calib.save(p)
    loaded = CalibrationResult.load(p)  # the extra block survives the file round trip
    page = build_report(loaded, truth)
    imgs = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert imgs, 'no embedded plot'
    for b in imgs:
        assert base64.b64decode(b)[:8] == b'\x89PNG\r\n\x1a\n'
    assert 'err/&sigma;' in page and 'gyro Kg[y,y]' in page
    # SRT has no history: said once, no empty sections
    assert page.count('Not in this report') == 1 and 'no estimate history' in page
    assert 'skipped' not in page and 'no SRT sequences' not in page
    assert 'http://' not in page and 'https://' not in page  # self-contained


def test_table_marks_fixed_and_highlights_only_estimated(srt_result):
    """SRT holds G, qa and the size effect fixed (and, on a 3-sequence plan, whatever the
    sequences do not excite): those cells say 'fixed', never an err/sigma against the
    prior; a highlighted cell is always an estimated one."""
    from imu_calib_ros.report import build_report
    calib, truth = srt_result
    page = build_report(calib, truth)
    for tag in ('gyro G[x,y]', 'accel quad[z]', 'size effect[x,y]'):
        # held at zero by the method: folded into one line, no rows of zeros
        assert not [r for r in page.split('<tr>') if r.startswith(f'<td>{tag}</td>')]
    folded = page.split('not estimated, held at zero: ')[1].split('<')[0]
    assert 'gyro G (' in folded and 'size effect (' in folded, folded
    not_est = calib.extra['srt']['not_estimated']
    assert 'ba_x' in not_est  # 3 sequences do not excite it ...
    row = next(r for r in page.split('<tr>') if r.startswith('<td>accel bias[x]</td>'))
    assert '>fixed</td>' in row
    row = next(r for r in page.split('<tr>') if r.startswith('<td>accel bias[y]</td>'))
    assert '>fixed</td>' not in row  # ... but ba_y (sequence 7) is estimated


def test_srt_plot_values_are_the_measured_change(srt_result):
    """The plotted Delta a_H is the change as measured before the SRT correction (tens to
    hundreds of ug from 20-ppm nav-grade errors times 2 pi g), not the ~0 left after it."""
    calib, _ = srt_result
    seqs = calib.extra['srt']['sequences']
    meas = np.array([v for s in seqs for v in s['delta_a_h_m_s2']])
    final = np.array([v for s in seqs for v in s['delta_a_h_final_m_s2']])
    sig = np.array([v for s in seqs for v in s['sigma_m_s2']])
    assert np.max(np.abs(meas) / sig) > 10  # well above the noise of a row
    # the correction took most of it out (what is left is the part of the parameters this
    # short plan does not determine better than the prior, held at their assumed values)
    assert np.max(np.abs(meas - final) / sig) > 10
    assert np.linalg.norm(final) < 0.5 * np.linalg.norm(meas)


def test_levelled_attitude_levels_and_keeps_heading():
    from imu_calib_ros.cli.report import levelled_attitude
    from imu_calib_ros.core.rotation import rotvec_to_matrix
    R_nom = rotvec_to_matrix(np.array([0.3, -0.2, 1.1]))
    tilt = rotvec_to_matrix(np.array([1.2e-3, -0.8e-3, 0.0]))  # ENU tilt the fixture misses
    R_true = tilt @ R_nom
    f_imu = R_true.T @ np.array([0.0, 0.0, 9.81])
    R = levelled_attitude(R_nom, f_imu)
    np.testing.assert_allclose(R @ f_imu, [0, 0, 9.81], atol=1e-12)
    # a pure tilt is undone exactly (minimal rotation about a horizontal axis)
    np.testing.assert_allclose(R, R_true, atol=1e-9)


def test_report_renders_in_chromium(srt_result, tmp_path):
    """Headless Chromium screenshot of a generated report: a PNG that is not blank."""
    exe = shutil.which('chromium') or shutil.which('chromium-browser')
    if exe is None:
        pytest.skip('chromium not installed (no chromium on PATH, e.g. /usr/bin/chromium): '
                    'render check skipped')
    import matplotlib.image
    from imu_calib_ros.report import build_report
    calib, truth = srt_result
    html_path = tmp_path / 'r.html'
    html_path.write_text(build_report(calib, truth))
    shot = tmp_path / 'r.png'
    subprocess.run([exe, '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic',
                    '--no-first-run', '--disable-background-networking',
                    '--disable-component-update', '--disable-sync',
                    f'--user-data-dir={tmp_path / "chromium-profile"}',
                    f'--screenshot={shot}', '--window-size=1200,2400', html_path.as_uri()],
                   check=True, timeout=90, capture_output=True)
    assert shot.exists(), 'chromium wrote no screenshot'
    data = shot.read_bytes()
    assert data[:8] == b'\x89PNG\r\n\x1a\n'
    img = matplotlib.image.imread(shot)[..., :3]
    assert img.shape[:2] == (2400, 1200)
    # not blank: a white page has zero variance; text, table lines and plots give
    # thousands of dark pixels and coloured (plot) pixels
    assert float(img.var()) > 1e-3, img.var()
    dark = (img.mean(axis=2) < 0.5).sum()
    coloured = (img.max(axis=2) - img.min(axis=2) > 0.2).sum()
    assert dark > 5000 and coloured > 2000, (dark, coloured)


@pytest.mark.parametrize('where', ['missing_dir/r.html', '.'])
def test_report_cli_bad_output_is_one_line_and_writes_nothing(srt_result, tmp_path, capsys,
                                                              where):
    from imu_calib_ros.cli import main
    calib, _ = srt_result
    p = tmp_path / 'c.yaml'
    calib.save(p)
    before = sorted(tmp_path.rglob('*'))
    assert main(['report', str(p), '--output', str(tmp_path / where)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and '--output' in err[0], err
    assert sorted(tmp_path.rglob('*')) == before
