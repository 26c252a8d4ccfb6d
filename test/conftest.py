"""One pytest-xdist worker runs every test that starts ROS nodes, one after another.

With ``pytest -n 2`` (``make test``) on a 2-core machine, two node graphs at once (each a
node, its estimator process, a simulator or bag player and the test's own node) left the
CPU-bound middleware threads so far behind that best-effort samples were dropped and a node
missed its shutdown deadline. A test module that imports ``start_node`` from
``ros_helpers`` (every test that runs nodes does) joins the group ``dds``; ``--dist
loadgroup`` (setup.cfg) sends a group to one worker while the other takes the rest.
"""
from __future__ import annotations

import os
import random
from typing import Any

import pytest

# Each xdist worker's ROS graphs on a domain of their own: worker i of n takes a random domain
# congruent to i + 1 modulo n (1..232), so two workers never share one. Test modules only
# setdefault it. Each module drawing its own 1..200 left both workers on the same domain one
# run in 200: a clean clone's `make test` once failed 23 node tests on cross-talk (wall-clock
# /diagnostics in a sim-time test, the arm node rejecting a table's joint states).
_WORKER = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
_INDEX = int(_WORKER[2:]) if _WORKER[2:].isdigit() else 0
_COUNT = max(int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1') or 1), _INDEX + 1)
_DOMAIN = 1 + _INDEX + _COUNT * random.randint(0, (231 - _INDEX) // _COUNT)
os.environ['ROS_DOMAIN_ID'] = str(_DOMAIN)


def pytest_collection_modifyitems(config: Any, items: list[pytest.Item]) -> None:
    for item in items:
        module = getattr(item, 'module', None)
        if module is not None and hasattr(module, 'start_node'):
            item.add_marker(pytest.mark.xdist_group('dds'))
