"""The worker processes' logging of a batch's own LocalCluster: :class:`QuietShutdownHeartbeat` drops the one ERROR
record with traceback that distributed's heartbeat logs when it races the cluster's shutdown; all others are kept.
"""
from __future__ import annotations

import logging

from distributed.diagnostics.plugin import WorkerPlugin

HEARTBEAT_FAILURE = "Failed to communicate with scheduler during heartbeat"


class HeartbeatFailureFilter(logging.Filter):
    """Rejects distributed.worker's record of a heartbeat whose comm to the scheduler closed."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(HEARTBEAT_FAILURE)


class QuietShutdownHeartbeat(WorkerPlugin):
    """Installs :class:`HeartbeatFailureFilter` on each worker's ``distributed.worker`` logger (also on a worker
    the nanny restarted: plugins are set up on every worker that joins)."""

    name = "needle-batch-quiet-shutdown-heartbeat"

    def setup(self, worker) -> None:
        logger = logging.getLogger("distributed.worker")
        if not any(isinstance(f, HeartbeatFailureFilter) for f in logger.filters):
            logger.addFilter(HeartbeatFailureFilter())
