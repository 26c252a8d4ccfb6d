"""One pytest-xdist worker runs every test that starts ROS nodes, one after another.

With ``pytest -n 2`` (``make test``) on a 2-core machine, two node graphs at once (each a
node, its estimator process, a simulator or bag player and the test's own node) left the
CPU-bound middleware threads so far behind that best-effort samples were dropped and a node
missed its shutdown deadline. A test module that imports ``start_node`` from
``ros_helpers`` (every test that runs nodes does) joins the group ``dds``; ``--dist
loadgroup`` (setup.cfg) sends a group to one worker while the other takes the rest.
"""
from __future__ import annotations

from typing import Any

import pytest


def pytest_collection_modifyitems(config: Any, items: list[pytest.Item]) -> None:
    for item in items:
        module = getattr(item, 'module', None)
        if module is not None and hasattr(module, 'start_node'):
            item.add_marker(pytest.mark.xdist_group('dds'))
