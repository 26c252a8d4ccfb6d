"""Motion plans: YAML step lists mapped onto a fixture as analytic joint-angle profiles.

A plan (``config/plans/NAME.yaml``, format in ``docs/PLANS.md``) lists steps (dwell, move,
rotate_imu, orient, set, oscillate, spin, srt_sequence, random_moves, include, repeat).
:func:`build_profile` maps it onto a :class:`~imu_calib_ros.core.fixture.Fixture` and returns
a :class:`JointProfile`: piecewise analytic ``q(t), q'(t), q''(t)`` (the pieces and why the
third derivative may jump only at its breakpoints: :mod:`.model`).

One module per concern (issue 14 item 6); this package re-exports their public names, so
``from imu_calib_ros.core.plans import build_profile, load_plan`` keeps working:

- :mod:`.model`: the plan objects (:class:`Step`, :class:`Plan`) and the profile
  (:class:`Segment`, :class:`JointProfile` and its analytic pieces);
- :mod:`.parse`: the plan files (YAML schema, ``include``/``repeat``, value checks,
  :data:`SRT_TABLE`, :func:`load_plan`, :func:`plan_from_dict`, :func:`random_plan`);
- :mod:`.builder`: the fixture builder (:func:`build_profile`: IMU axes resolved through the
  fixture's kinematics, attitudes solved, URDF limits checked).
"""
from .builder import (AXIS_TOL_RAD, DEFAULT_MAX_ACCEL_RAD_S2, DEFAULT_MAX_RATE_RAD_S,
                      MIN_MOVE_S, build_profile)
from .model import JointProfile, Plan, Segment, Step
from .parse import SRT_TABLE, load_plan, plan_from_dict, random_plan, resolve_plan_path

__all__ = ['AXIS_TOL_RAD', 'DEFAULT_MAX_ACCEL_RAD_S2', 'DEFAULT_MAX_RATE_RAD_S', 'MIN_MOVE_S',
           'SRT_TABLE', 'JointProfile', 'Plan', 'Segment', 'Step', 'build_profile',
           'load_plan', 'plan_from_dict', 'random_plan', 'resolve_plan_path']
