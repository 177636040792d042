"""Subscriptions that their owner's thread drains, instead of an executor.

The simulator's integration loop takes the waiting poses itself at each tick, right before it steps (no executor,
no thread hand-over: why, docs/design_notes.md); between ticks it waits on its own wait set
(:class:`MessageWaiter`), so a pose arriving mid-period is taken at once. The subscription is a normal one (graph,
QoS, remapping) in a callback group that no executor runs.
"""
from __future__ import annotations

from contextlib import ExitStack
from typing import Sequence

from rclpy.callback_groups import CallbackGroup
from rclpy.context import Context
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription


class PolledCallbackGroup(CallbackGroup):
    """Entities polled by their owner: an executor never waits on them nor runs their callbacks."""

    def can_execute(self, entity) -> bool:
        return False

    def beginning_execution(self, entity) -> bool:
        return False

    def ending_execution(self, entity) -> None:
        pass


def drain(subscription: Subscription, limit: int = 10_000, run_callback: bool = True) -> int:
    """Run the subscription's callback on every message waiting in its queue, oldest first (at most ``limit``),
    with the message info if the callback takes it, as rclpy's executor calls it (``run_callback`` False: drop
    them); returns how many there were."""
    count = 0
    with_info = subscription._callback_type is Subscription.CallbackType.WithMessageInfo  # as the executor reads it
    with subscription.handle:
        while count < limit:
            taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
            if taken is None:
                break
            if run_callback:
                subscription.callback(*(taken if with_info else taken[:1]))
            count += 1
    return count


class MessageWaiter:
    """Blocks its owner's thread (GIL released) until a polled subscription has a message waiting, or a timeout
    passes. One rcl wait set, made at the first wait and kept; the subscriptions and the context are held in use
    during each wait (a node or context torn down meanwhile is destroyed after it), and :meth:`close` destroys the
    wait set once no wait uses it. One thread waits on it."""

    def __init__(self, subscriptions: Sequence[Subscription], context: Context) -> None:
        self._subscriptions = list(subscriptions)
        self._context = context
        self._wait_set = None

    def wait(self, timeout: float) -> list[Subscription]:
        """The subscriptions with a message waiting within ``timeout`` [s] (left in their queues for :func:`drain`);
        empty if none came."""
        with ExitStack() as in_use:
            for subscription in self._subscriptions:
                in_use.enter_context(subscription.handle)
            in_use.enter_context(self._context.handle)
            if self._wait_set is None:
                self._wait_set = _rclpy.WaitSet(len(self._subscriptions), 0, 0, 0, 0, 0, self._context.handle)
            wait_set = self._wait_set
            in_use.enter_context(wait_set)
            wait_set.clear_entities()
            for subscription in self._subscriptions:
                wait_set.add_subscription(subscription.handle)
            wait_set.wait(max(int(timeout * 1e9), 0))
            ready = wait_set.get_ready_entities("subscription")
            return [subscription for subscription in self._subscriptions if subscription.handle.pointer in ready]

    def close(self) -> None:
        """Destroy the wait set (after the wait in progress, if any); a later :meth:`wait` makes a new one."""
        wait_set, self._wait_set = self._wait_set, None
        if wait_set is not None:
            wait_set.destroy_when_not_in_use()
