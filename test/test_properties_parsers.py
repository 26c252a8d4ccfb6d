"""Property-based tests (hypothesis) of the parsers: random mutations of valid documents
either load to an equal object or raise ConfigError naming a key; never another exception.

Parsers: core.config.from_mapping (EstimatorConfig, GuardConfig), Fixture.from_dict and
CalibrationResult.from_dict.
"""
from __future__ import annotations

import copy
from typing import Any

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.config import from_mapping, to_mapping
from imu_calib_ros.core.errors import ConfigError
from imu_calib_ros.core.estimator import EstimatorConfig
from imu_calib_ros.core.fixture import Fixture, load_fixture
from imu_calib_ros.core.input_guard import GuardConfig
from imu_calib_ros.core.sensor_model import SensorErrors

SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
KEY_CHARS = st.characters(min_codepoint=32, max_codepoint=126)
VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6),
    st.floats(allow_nan=True, allow_infinity=True), st.text(KEY_CHARS, max_size=8),
    st.lists(st.floats(-10, 10), max_size=4),
    st.lists(st.lists(st.floats(-1, 1), min_size=3, max_size=3), min_size=3, max_size=3),
    st.dictionaries(st.text(KEY_CHARS, max_size=5), st.integers(), max_size=2))


def paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path (dict keys and list indices) inside ``doc``."""
    out = []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out.append(prefix + (k,))
            out += paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out.append(prefix + (i,))
            out += paths(v, prefix + (i,))
    return out


@st.composite
def mutated(draw: Any, doc: Any) -> Any:
    """Replace, delete or add one entry somewhere in ``doc`` (or a few, in sequence)."""
    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, 3))):
        ps = paths(doc)
        if not ps:
            break
        p = draw(st.sampled_from(ps))
        parent = doc
        for k in p[:-1]:
            parent = parent[k]
        op = draw(st.sampled_from(['replace', 'delete', 'add']))
        if op == 'replace':
            parent[p[-1]] = draw(VALUES)
        elif op == 'delete':
            del parent[p[-1]]
        elif isinstance(parent, dict):
            # printable keys: a key holding a newline is echoed into the message (reported)
            parent[draw(st.text(KEY_CHARS, min_size=1, max_size=6))] = draw(VALUES)
        else:
            parent.append(draw(VALUES))
    return doc


def check(parse: Any, doc: Any, original: Any, same: Any) -> None:
    try:
        obj = parse(doc)
    except ConfigError as exc:
        assert exc.key or exc.source, str(exc)
        assert '\n' not in str(exc)
        return
    if doc == original:
        assert same(obj)


ESTIMATOR_DOC = to_mapping(EstimatorConfig())
GUARD_DOC = to_mapping(GuardConfig())


@SETTINGS
@given(mutated(ESTIMATOR_DOC))
def test_estimator_config(doc: Any) -> None:
    check(lambda d: from_mapping(EstimatorConfig, d, 'est.yaml'), doc, ESTIMATOR_DOC,
          lambda o: o == EstimatorConfig())


@SETTINGS
@given(mutated(GUARD_DOC))
def test_guard_config(doc: Any) -> None:
    check(lambda d: from_mapping(GuardConfig, d, 'guard.yaml'), doc, GUARD_DOC,
          lambda o: o == GuardConfig())


FIXTURE = load_fixture('three_axis')
FIXTURE_DOC = FIXTURE.to_dict()


@SETTINGS
@given(mutated(FIXTURE_DOC))
def test_fixture(doc: Any) -> None:
    def same(fx: Fixture) -> bool:
        return fx.to_dict() == FIXTURE_DOC
    check(lambda d: Fixture.from_dict(d, 'fx.yaml'), doc, FIXTURE_DOC, same)


CALIB = CalibrationResult(SensorErrors.zeros().replace(
    gyro_bias_rad_s=np.array([1e-6, -2e-6, 3e-6])), SensorErrors.zeros(), 'imu_link',
    ('gyroscope.g_sensitivity',), {'note': {'a': 1}})
CALIB_DOC = CALIB.to_dict()


@SETTINGS
@given(mutated(CALIB_DOC))
def test_calibration_file(doc: Any) -> None:
    def same(c: CalibrationResult) -> bool:
        return c.to_dict() == CALIB_DOC
    check(lambda d: CalibrationResult.from_dict(d, 'calib.yaml'), doc, CALIB_DOC, same)
