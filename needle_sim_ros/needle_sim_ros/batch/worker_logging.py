"""The worker processes' logging of a batch's own LocalCluster: distributed's heartbeat that races the cluster's
shutdown (the scheduler closes its comms while a worker's heartbeat is in flight) logs "Failed to communicate with
scheduler during heartbeat." with a traceback at ERROR; :class:`QuietShutdownHeartbeat` drops that one record so a
batch's stderr has only its own report. Every other worker log record is kept."""
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
