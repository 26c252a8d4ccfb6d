"""The parameter registry (issue 14 item 5): it lists exactly CONTRACT 4's parameters in the
calibration file's order, and every ordering, unit table and grade-to-sigma map of the code
derives from it."""
import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from imu_calib_ros.core import parameters as registry
from imu_calib_ros.core import sensor_model as sm
from imu_calib_ros.core import units
from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.estimator import error_model as em
from imu_calib_ros.core.estimator import priors
from imu_calib_ros.core.estimator.config import EstimatorConfig
from imu_calib_ros.core.estimator.result import CONTRACT_KEYS
from imu_calib_ros.core.imu_grade import ErrorSigmas, load_grade
from imu_calib_ros.core.methods import srt
from imu_calib_ros.testing import world_cases

ROOT = Path(__file__).resolve().parents[1]


def _contract_keys() -> list[str]:
    """The parameter keys of CONTRACT 4's file example, in its order (docs/CONTRACT.md)."""
    text = (ROOT / 'docs' / 'CONTRACT.md').read_text()
    block = text.split('## 4.')[1].split('```yaml')[1].split('```')[0]
    keys, section = [], None
    for line in block.splitlines():
        m = re.match(r'^  (\w+):', line)
        if m:
            section = m.group(1) if m.group(1) in ('gyroscope', 'accelerometer') else None
            continue
        m = re.match(r'^    (\w+):', line)
        if m and section:
            keys.append(f'{section}.{m.group(1)}')
    return keys


def test_registry_is_contract_4_in_file_order(tmp_path) -> None:
    """The registry's parameters are CONTRACT 4's, in the order of its example and of the
    file the code writes."""
    assert list(registry.PARAMETER_KEYS) == _contract_keys()
    assert len(registry.PARAMETER_KEYS) == 9
    p = tmp_path / 'c.yaml'
    CalibrationResult.exact(sm.SensorErrors.zeros()).save(p)
    doc = yaml.safe_load(p.read_text())['imu_calibration']
    written = [f'{s}.{k}' for s in ('gyroscope', 'accelerometer') for k in doc[s]]
    assert written == list(registry.PARAMETER_KEYS)
    fields = [f.name for f in dataclasses.fields(sm.SensorErrors)]
    assert fields == [q.field for q in registry.PARAMETERS]


def test_parameter_entries() -> None:
    """45 free entries: Kg's upper triangle only, no size-effect diagonal; every entry of a
    sensor parameter in exactly one group, and every group inside its parameter."""
    assert sum(len(q.entries) for q in registry.PARAMETERS) == sm.N_PARAMETERS == 45
    for q in registry.PARAMETERS:
        in_groups = [i for g in registry.SENSOR_GROUPS if g.key == q.key for i in g.entries]
        assert sorted(in_groups) == sorted(q.entries), q.key
        assert len(set(q.entries)) == len(q.entries)
        assert all(len(i) == len(q.shape) for i in q.entries)
    assert registry.parameter('accelerometer.size_effect').canonical((1, 1)) is None
    assert registry.parameter('gyroscope.scale_misalignment').canonical((2, 0)) == (0, 2)
    # every group with a grade prior names a field of ErrorSigmas; every field is used
    fields = {f.name for f in dataclasses.fields(ErrorSigmas)}
    used = [g.grade_field for g in registry.SENSOR_GROUPS]
    assert sorted(used) == sorted(fields)


def test_sensor_model_layout_derives_from_registry() -> None:
    assert sm.PARAMETER_KEYS == registry.PARAMETER_KEYS
    assert list(sm.KEY_OF_FIELD.items()) == [(q.field, q.key) for q in registry.PARAMETERS]
    names = [q.entry_name(i) for q in registry.PARAMETERS for i in q.entries]
    assert list(sm.PARAMETER_NAMES) == names
    assert sm.PARAMETER_NAMES[3:9] == tuple(f'gyroscope.scale_misalignment[{a}]' for a in
                                            ('xx', 'yy', 'zz', 'xy', 'xz', 'yz'))
    x = np.arange(45.0) * 1e-6
    assert np.array_equal(sm.SensorErrors.from_vector(x).as_vector(), x)


def test_units_derive_from_registry() -> None:
    """The display units (units.ENGINEERING), the filter's (error_model.GROUPS), the world
    cases' and the registry agree, value for value."""
    assert list(units.ENGINEERING) == list(registry.PARAMETER_KEYS)
    for q in registry.PARAMETERS:
        label, si, unit = units.ENGINEERING[q.key]
        g = registry.group_of_entry(q.key, q.entries[0])
        assert (label, si, unit) == (q.label, g.si_per_unit, g.unit)
        for idx in np.ndindex(q.shape):
            g = registry.group_of_entry(q.key, idx) or registry.display_group(q.key)
            assert units.element_unit(q.key, idx) == g.unit
    assert units.element_unit('gyroscope.scale_misalignment', (1, 0)) == 'urad'
    assert units.element_unit('accelerometer.scale_misalignment', (2, 2)) == 'ppm'
    assert units.ENGINEERING['gyroscope.bias'][1] == pytest.approx(np.pi / 180 / 3600, rel=1e-15)
    assert units.ENGINEERING['accelerometer.quadratic'][1] == 1e-6 * 9.80665 / 9.80665 ** 2
    assert em.GROUPS == tuple((g.name, g.size, g.si_per_unit, g.unit, g.side)
                              for g in registry.GROUPS)
    # the world oracle keeps its own tables, written from CONTRACT alone (docs/WORLD.md);
    # they agree with the registry
    assert world_cases.PARAMETER_KEYS == registry.PARAMETER_KEYS
    for g in registry.SENSOR_GROUPS:
        assert world_cases.ENGINEERING_UNITS[g.name] == (g.si_per_unit, g.unit)
    for q in registry.PARAMETERS:
        assert world_cases._entries(q.key) == [  # noqa: SLF001
            (f'{g.name}[{g.entry_name(k)}]', g.name, idx)
            for g in map(registry.group, registry.GROUPS_OF_KEY[q.key])
            for k, idx in enumerate(g.entries)], q.key


def test_filter_theta_derives_from_registry() -> None:
    """error_model's theta: the registry's groups of each side, in order; the conversions
    to and from SensorErrors put every entry where the registry says."""
    assert em.GYRO_GROUPS == tuple(g.name for g in registry.GROUPS if g.side == 'g')
    assert em.ACCEL_GROUPS == tuple(g.name for g in registry.GROUPS if g.side == 'a')
    # 21 and 24 sensor errors, the time offset and the two sampling kernels
    assert (em.N_GYRO, em.N_ACCEL) == (22, 26)
    assert CONTRACT_KEYS == registry.GROUPS_OF_KEY
    rng = np.random.default_rng(0)
    e = sm.SensorErrors.from_vector(rng.normal(size=45))
    tg, ta = em.theta_from_errors(e)
    for g in registry.SENSOR_GROUPS:
        theta, cols = (tg, em.gyro_cols(g.name)) if g.side == 'g' else (ta, em.accel_cols(g.name))
        q = registry.parameter(g.key)
        assert np.array_equal(theta[cols], [getattr(e, q.field)[i] for i in g.entries]), g.name
    assert ta[-1] == 0.0  # the time offset
    assert np.array_equal(em.errors_from_theta(tg, ta, sm.SensorErrors).as_vector(),
                          e.as_vector())
    # the estimator's switches name the registry's groups, in its order
    groups = EstimatorConfig(estimate_time_offset=True, estimate_gyro_g_sensitivity=True,
                             attitude_aiding=True).estimated_groups
    assert groups == tuple(g.name for g in registry.GROUPS if g.name in groups)


def test_srt_parameters_derive_from_registry() -> None:
    assert len(srt.PARAMS) == 24 and srt.N_GYRO_PARAMS == 9
    assert srt.PARAM_NAMES[:9] == ('Kg_xx', 'Kg_yy', 'Kg_zz', 'Kg_xy', 'Kg_xz', 'Kg_yz',
                                   'ag_x', 'ag_y', 'ag_z')
    assert srt.PARAM_NAMES[9:18] == tuple(f'Ka_{a}{b}' for a in 'xyz' for b in 'xyz')
    assert srt.PARAM_NAMES[18:] == ('aa_x', 'aa_y', 'aa_z', 'ba_x', 'ba_y', 'ba_z')
    for name, fld, idx in srt.PARAMS:
        q = registry.PARAMETER_OF_FIELD[fld]
        assert idx in q.entries and name == q.symbol_name(idx)
    assert [c[0] for c in srt.CONSIDER] == (
        [f'G_{a}{b}' for a in 'xyz' for b in 'xyz'] + ['qa_x', 'qa_y', 'qa_z']
        + ['r_xy', 'r_xz', 'r_yx', 'r_yz', 'r_zx', 'r_zy'])
    assert np.array_equal(srt._EPS, [1e-6] * 21 + [1e-5] * 3)  # noqa: SLF001


@pytest.mark.parametrize('name', ['nav_grade', 'mems_mti1'])
def test_grade_sigma_maps_agree(name) -> None:
    """The estimator's prior (without a coarse start) and the methods' assumed sigmas are
    the same grade sigmas, entry by entry."""
    grade = load_grade(name)
    cfg = EstimatorConfig()
    prior = priors.prior_sigmas(grade, cfg)
    assumed = srt._grade_sigmas(grade)  # noqa: SLF001
    assert list(assumed) == [q.field for q in registry.PARAMETERS]
    for g in registry.SENSOR_GROUPS:
        s = float(getattr(grade.sigma, g.grade_field))
        q = registry.parameter(g.key)
        assert all(assumed[q.field][i] == s for i in g.entries), g.name
        if q.symmetric:
            assert all(assumed[q.field][i[::-1]] == s for i in g.entries), g.name
        exp = s * cfg.prior_sigma_scale
        if g.name == 'gyro_bias':
            exp = np.hypot(exp, grade.gyro_bias_instability_rad_s)
        elif g.name == 'accel_bias':
            exp = np.hypot(exp, grade.accel_bias_instability_m_s2)
        assert np.array_equal(prior[g.name], np.full(g.size, exp)), g.name
    assert np.all(np.diag(assumed['size_effect_m']) == 0.0)
    assert list(priors.RAW_PRIOR) == [g.name for g in registry.SENSOR_GROUPS]
    assert set(priors.COARSE_FLOOR) == set(priors.RAW_PRIOR)
    assert all(not np.any(v) for v in srt._grade_sigmas(None).values())  # noqa: SLF001


def test_misspelt_method_option_raises() -> None:
    """The methods take typed frozen options: a misspelt option is an error, not ignored
    (the old ``**_`` swallowed it)."""
    from imu_calib_ros.core.methods import modulation, oscillation
    for cls in (srt.SrtOptions, oscillation.OscillationOptions, modulation.DemodulationOptions):
        with pytest.raises(TypeError):
            cls(min_windows_s=2.0)
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(cls(), 'min_window_s', 2.0)
    for fn in (srt.estimate, srt.calibrate, oscillation.estimate, oscillation.calibrate):
        with pytest.raises(TypeError):
            fn(None, None, None, None, iteratons=2)
        with pytest.raises(TypeError):
            fn(None, None, None, None, min_window_s=2.0)  # an option, not a keyword
    with pytest.raises(TypeError):
        modulation.demodulate(None, None, None, 'continuous', causal=True)


def test_method_options_are_used() -> None:
    """An option reaches its method (the shortest window here), and the method returns a
    CalibrationResult."""
    from imu_calib_ros.core.errors import InputError
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.methods import oscillation
    from imu_calib_ros.core.plans import build_profile, load_plan
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fx = load_fixture('three_axis')
    grade = load_grade('nav_grade')
    sim = simulate(fx, build_profile(load_plan('demo_short'), fx), grade,
                   SimConfig(imu_rate_hz=50, seed=1))
    with pytest.raises(InputError, match='10000.0 s'):
        srt.calibrate(sim.imu, sim.joints, fx, grade, srt.SrtOptions(min_window_s=1e4))
    with pytest.raises(InputError):
        oscillation.calibrate(sim.imu, sim.joints, fx, grade,
                              oscillation.OscillationOptions(min_window_s=1e4))
    res = srt.calibrate(sim.imu, sim.joints, fx, grade, srt.SrtOptions(iterations=1))
    assert isinstance(res, CalibrationResult) and res.extra['method'] == 'srt'
    assert len(res.extra['srt']['iterations']) == 1


def test_raw_priors_cover_the_worlds_raw_units() -> None:
    """An uncalibrated unit's prior (``estimator.priors.RAW_PRIOR``, the registry's) is at
    least the largest raw error any of the world's unit classes draws (its own tables,
    ``testing/world_units.py``, from datasheets). A prior narrower than real parts is a
    silent wrong calibration wherever a plan leaves the group to it: with G's at 0.01
    (deg/s)/g (a tenth of its comment's 0.1) a consumer unit's G ended 6.2 sigma off on a
    12-move random plan, the self-check passed. The coarse fit's gyro prior is the same."""
    from imu_calib_ros.core.estimator.coarse import GYRO_FIT_SD0
    from imu_calib_ros.core.estimator.priors import RAW_PRIOR
    from imu_calib_ros.testing import world_units as wu
    g0 = 9.80665
    specs = wu.SPECS.values()
    scale = max(s.scale for s in specs)
    worst = {
        'gyro_bias': max(s.gyro_bias_rad_s for s in specs),
        'gyro_scale': scale, 'accel_scale': scale,
        'gyro_asymmetry': wu.ASYMMETRY_FRACTION * scale,
        'accel_asymmetry': wu.ASYMMETRY_FRACTION * scale,
        'gyro_misalignment': max(s.misalignment_rad for s in specs),
        'accel_misalignment': max(s.misalignment_rad for s in specs),
        'gyro_g_sensitivity': max(s.g_sensitivity[1] for s in specs),
        'accel_bias': max(s.accel_bias_m_s2 for s in specs),
        'accel_quadratic': wu.QUADRATIC_UG_G2[1] * 1e-6 / g0,  # ug/g^2 -> 1/(m/s^2)
        'size_effect': max(s.size_effect_m for s in specs),
    }
    assert set(worst) == set(RAW_PRIOR)
    for name, w in worst.items():
        assert RAW_PRIOR[name] >= w * (1.0 - 1e-12), (name, RAW_PRIOR[name], w)
    assert worst['gyro_g_sensitivity'] == pytest.approx(0.1 * np.pi / 180.0 / g0, rel=1e-12)
    assert GYRO_FIT_SD0[4:7] == pytest.approx([RAW_PRIOR['gyro_g_sensitivity']] * 3, rel=0)
    assert GYRO_FIT_SD0[[0, 3, 7]] == pytest.approx(
        [RAW_PRIOR['gyro_scale'], RAW_PRIOR['gyro_asymmetry'], RAW_PRIOR['gyro_bias']], rel=0)
