"""Input paths that bypass rclpy's executor: the one module built on rclpy internals.

Everything here depends on internals of rclpy 7.1 (ROS 2 Jazzy) that are not its public API;
an rclpy upgrade must check them first (issue 14 item 2):

- ``Subscription.handle.take_message(msg_type, raw)`` (the pybind ``_rclpy.Subscription``),
  with the handle used as a context manager (``with sub.handle:``), and the subscription's
  ``msg_type`` and ``raw`` attributes: what ``Executor._take_subscription`` does;
- ``rclpy.impl.implementation_singleton.rclpy_implementation.WaitSet(...)`` with
  ``clear_entities``, ``add_subscription``, ``add_guard_condition`` and ``wait(timeout_ns)``,
  and the ``handle`` of ``Context`` and ``GuardCondition`` (also context managers);
- ``CallbackGroup.can_execute`` / ``beginning_execution`` / ``ending_execution``: a group
  that always refuses keeps the executor off the subscription (:class:`_NeverInExecutor`).

:class:`InputThread` (the nodes' IMU and joint-state input) serves one subscription from a
dedicated thread; :class:`DrainingSubscription` (benchmarks and tests) takes a whole burst
per executor callback.
"""
from __future__ import annotations

import threading
from typing import Any, Callable

from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from rclpy.qos import QoSProfile


class DrainingSubscription:
    """A subscription whose callback also takes every message already waiting.

    rclpy's Python executors cost a few hundred microseconds per callback (wait-set rebuild,
    a coroutine and a task per message), which at 1-5 kHz is most of a core. After the
    executor delivers one message, :meth:`_on_wake` takes the rest of the queue directly
    from the subscription handle (what ``Executor._take_subscription`` does) up to
    ``max_per_wake``, so the executor's cost is paid once per burst instead of per message.
    ``handle(msg)`` is called for every message, in arrival order.
    """

    def __init__(self, node: Node, msg_type: Any, topic: str, handle: Callable[[Any], None],
                 qos: QoSProfile, max_per_wake: int = 1000, **kwargs: Any):
        from rclpy.event_handler import SubscriptionEventCallbacks
        self._handle = handle
        self._max = max_per_wake
        self.wakes = 0
        self.messages = 0
        self.lost = 0  # messages the middleware reports as lost (DDS SAMPLE_LOST), if supported
        events = SubscriptionEventCallbacks(message_lost=self._on_lost)
        try:
            self.sub = node.create_subscription(msg_type, topic, self._on_wake, qos,
                                                event_callbacks=events, **kwargs)
        except Exception:  # noqa: BLE001 - rmw without the message-lost event
            self.sub = node.create_subscription(msg_type, topic, self._on_wake, qos, **kwargs)

    def _on_lost(self, status: Any) -> None:
        self.lost += int(status.total_count_change)

    def _on_wake(self, msg: Any) -> None:
        self.wakes += 1
        self._handle(msg)
        n = 1
        sub = self.sub
        handle = self._handle
        try:
            with sub.handle:
                take = sub.handle.take_message
                while n < self._max:
                    info = take(sub.msg_type, sub.raw)
                    if info is None:
                        break
                    handle(info[0])
                    n += 1
        finally:
            self.messages += n


class _NeverInExecutor(CallbackGroup):
    """A callback group the executor never runs: its entities are served by our own thread."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        pass


class InputThread:
    """One subscription served by a dedicated thread: wait, take the whole burst, handle.

    Measured on this 2-core machine at 1 kHz: rclpy's Python executor spends ~0.4 ms per
    wake rebuilding its wait set (every timer, service, guard condition and QoS-event
    handler of the node), which made the IMU callback path cost ~80 % of a core and its
    queueing the p99 latency. Here the subscription sits in a callback group the executor
    never runs, and this thread waits on a wait set holding only it (plus a stop guard
    condition), in C without the GIL, then takes every waiting message
    (``Subscription.handle.take_message``, what the executor does) and calls
    ``handle(msg)`` for each, in arrival order. ``handle`` runs in this thread: it must only
    touch state that is safe to share (counters, deques, atomic attribute swaps).
    ``raw=True`` hands over the serialised bytes (no Python message object is built).
    ``idle()``, if given, runs in this thread after every burst and wait; it returns the
    seconds until it wants to run again (None: no hurry), e.g. to release samples held by a
    :class:`~imu_calib_ros.core.reorder.ReorderBuffer` when the stream pauses.
    """

    def __init__(self, node: Node, msg_type: Any, topic: str, handle: Callable[[Any], None],
                 qos: QoSProfile, name: str = 'input', raw: bool = False,
                 idle: Callable[[], float | None] | None = None):
        self._handle = handle
        self._idle = idle
        self._context = node.context
        group = _NeverInExecutor()
        self.sub = node.create_subscription(msg_type, topic, handle, qos, callback_group=group,
                                            raw=raw)
        self._gc = node.create_guard_condition(lambda: None, callback_group=group)
        self.wakes = 0
        self.messages = 0
        self._stop = False
        self.error = ''
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
        sub, handle, idle = self.sub, self._handle, self._idle
        context: Any = self._context  # its .handle: Optional in rclpy's annotations
        longest = 200_000_000  # 0.2 s: also notices a shut-down context
        timeout = longest
        try:
            with context.handle, sub.handle, self._gc.handle:
                ws = _rclpy.WaitSet(1, 1, 0, 0, 0, 0, context.handle)
                take = sub.handle.take_message
                while not self._stop and self._context.ok():
                    ws.clear_entities()
                    ws.add_subscription(sub.handle)
                    ws.add_guard_condition(self._gc.handle)
                    ws.wait(timeout)
                    self.wakes += 1
                    while not self._stop:
                        info = take(sub.msg_type, sub.raw)
                        if info is None:
                            break
                        self.messages += 1
                        handle(info[0])
                    if idle is not None:
                        again = idle()
                        timeout = longest if again is None else \
                            min(longest, max(int(again * 1e9), 100_000))
        except Exception as exc:  # noqa: BLE001 - shutdown races; reported by the node
            if not self._stop and self._context.ok():
                self.error = f'{type(exc).__name__}: {exc}'

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self) -> None:
        """End the thread (before the node is destroyed)."""
        self._stop = True
        try:
            self._gc.trigger()
        except Exception:  # noqa: BLE001 - context already shut down
            pass
        self._thread.join(2.0)
