"""Managed-node helpers (REP 2002 lifecycle, ``rclpy.lifecycle``) for the needle simulator: a bringup sequences it with
``ros2 lifecycle set needle_simulator configure|activate|deactivate|cleanup``; with ``autostart`` (the default) it
configures and activates itself, so ``ros2 run`` behaves like a plain node.
"""
from __future__ import annotations

from typing import Callable

from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn

from needle_common.parameters import ParameterError

SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE


def autostart(node: LifecycleNode) -> None:
    """configure, then activate; a failed configure raises :class:`ParameterError` (the node exits with 2)."""
    if node.trigger_configure() != SUCCESS:
        raise ParameterError(getattr(node, "configure_error", "") or "configure failed (see the log)")
    if node.trigger_activate() != SUCCESS:
        raise ParameterError("activate failed (see the log)")


def when_configured(is_configured: Callable[[], bool], callback: Callable) -> Callable:
    """A service callback that answers ``success = False`` until the node is configured."""
    def guarded(request, response):
        if not is_configured():
            response.success, response.message = False, "the node is not configured (lifecycle: configure it first)"
            return response
        return callback(request, response)

    return guarded
