"""rclpy nodes (issue 4): thin shells that convert messages, call the core and publish.

One node per module, ``main()`` is the console-script target and the ``python -m`` entry:
``calibration``, ``compensator``, ``turntable_sim``, ``turntable_driver``. Shared shell helpers
(parameters from a typed config dataclass, the start/stop form, QoS profiles, the streaming
compensation used by both the compensator and the calibration node) are in :mod:`.common`.
"""
