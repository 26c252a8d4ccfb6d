"""core.estimator.replay: the batch path (bag windows, push_joint_batch) gives exactly the
estimate of the sample-by-sample path, for any window size (push-pattern invariance)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imu_calib_ros.cli import main
from imu_calib_ros.core.estimator import EstimatorConfig
from imu_calib_ros.core.estimator.replay import replay_pass
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from msg_adapters.bag import iter_bag

FX = load_fixture('three_axis')
GRADE = load_grade('nav_grade')


@pytest.fixture(scope='module')
def bag(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp('replay_batches')
    assert main(['simulate', '--fixture', 'three_axis', '--plan', 'demo_short', '--imu',
                 'nav_grade', '--rate', '100', '--seed', '5', '--output',
                 str(d / 'bag.mcap')]) == 0
    return d / 'bag.mcap'


class _Windows:
    """iter_bag's samples with a chosen batch window."""

    def __init__(self, path: Path, window: int) -> None:
        self.path, self.window = path, window

    def batches(self):  # noqa: ANN201
        return iter_bag(self.path).batches(self.window)


def test_batch_replay_equals_sample_replay(bag: Path) -> None:
    cfg = EstimatorConfig(estimate_time_offset=True)
    ref = replay_pass(iter(list(iter_bag(bag))), FX, GRADE, cfg, batch=777)  # samples
    a = ref.estimate_state()
    for src in (iter_bag(bag), _Windows(bag, 999)):
        est = replay_pass(src, FX, GRADE, cfg)
        b = est.estimate_state()
        assert est.counters == ref.counters
        assert est.health()['gate_accepted'] == ref.health()['gate_accepted']
        sig = np.sqrt(np.diag(a.covariance))
        # the same arithmetic: only the push pattern differs
        assert np.max(np.abs(b.values - a.values) / sig) < 1e-9
        np.testing.assert_allclose(np.sqrt(np.diag(b.covariance)), sig, rtol=1e-12)
    assert ref.counters['imu_processed'] > 0.95 * ref.counters['imu_samples']  # all but init
