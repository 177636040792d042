"""Subscriptions that their owner's thread drains, instead of an executor.

rclpy's executor builds a wait set and a task for every message: ~100 µs of Python per callback, which at
1 kHz of base poses costs a tenth of a core and, worse, makes the integration thread wait for the GIL while the
executor thread works. The simulator's integration loop instead takes the waiting poses itself at each tick,
right before it steps: no wait set, no thread hand-over, the newest pose is used at once. The subscription is
a normal one (graph, QoS, remapping, ``ros2 topic info``); it only belongs to a callback group that no executor
runs.
"""
from __future__ import annotations

from rclpy.callback_groups import CallbackGroup
from rclpy.subscription import Subscription


class PolledCallbackGroup(CallbackGroup):
    """Entities polled by their owner: an executor never waits on them nor runs their callbacks."""

    def can_execute(self, entity) -> bool:
        return False

    def beginning_execution(self, entity) -> bool:
        return False

    def ending_execution(self, entity) -> None:
        pass


def drain(subscription: Subscription, limit: int = 10_000) -> int:
    """Run the subscription's callback on every message waiting in its queue, oldest first (at most ``limit``);
    returns how many there were."""
    count = 0
    with subscription.handle:
        while count < limit:
            taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
            if taken is None:
                break
            subscription.callback(taken[0])
            count += 1
    return count
