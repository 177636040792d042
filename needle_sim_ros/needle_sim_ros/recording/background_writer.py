"""An :class:`McapBagWriter` in a child process, for producers that are CPU-bound themselves.

The offline pipeline produces ~1300 messages per second of bag (a wrench per 1 ms step); the mcap library spends
~20 µs of Python on each, a fifth of the pipeline's time. Here the producer only appends (topic, bytes, log time)
to a list that goes to the child in batches; the child writes them in the same order, on the other core. The file
is the same as a :class:`McapBagWriter` in the producer's process would write. Errors (an unwritable path, a full
disk) come back as :class:`RecordingError` with the writer's message, at the next batch or at :meth:`close`.
"""
from __future__ import annotations

import os
import pickle
import select
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any, BinaryIO, Sequence

from needle_sim_ros.recording.mcap_writer import McapBagWriter, RecordingError, WriterOptions
from needle_common.qos import OfferedQos

BATCH = 256  # messages per hand-over (the last one is written while the producer waits in close)


def serve(requests: BinaryIO, replies: BinaryIO) -> None:
    """Child side: build the writer from the first frame (path, options), then execute the batches of calls in
    order; report an error at once and, on close, the files written."""
    def reply(kind: str, value: Any) -> None:
        pickle.dump((kind, value), replies)
        replies.flush()

    path, options = pickle.load(requests)
    try:
        writer = McapBagWriter(path, options)
    except (RecordingError, ValueError, OSError) as error:
        reply("error", f"{error}")
        return
    try:
        while True:
            for call, arguments in pickle.load(requests):
                if call == "close":
                    reply("closed", [str(p) for p in writer.close()])
                    return
                getattr(writer, call)(*arguments)
    except Exception as error:  # noqa: BLE001 - every failure must reach the producer
        reply("error", f"{type(error).__name__}: {error}")
        writer.close()


class BackgroundBagWriter:
    """``add_topic``, ``write`` and ``close`` as :class:`McapBagWriter`, executed by a child Python process
    (started as ``python -m needle_sim_ros.recording.background_writer``, so it works from any script)."""

    def __init__(self, path: str | os.PathLike, options: WriterOptions = WriterOptions()) -> None:
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        self._process = subprocess.Popen([sys.executable, "-m", __name__], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, env=env)
        self._pending: list[tuple[str, tuple]] = [("start", (str(path), options))]
        self._closed = False  # the child starts (~0.3 s) while the producer works; errors come with the next batch
        self._send()

    def add_topic(self, topic: str, type_name: str, offered_qos: Sequence[OfferedQos] = (OfferedQos(),)) -> None:
        self._call("add_topic", (topic, type_name, tuple(offered_qos)))

    def write(self, topic: str, data: bytes, log_time_ns: int) -> None:
        self._call("write", (topic, data, log_time_ns))

    def close(self) -> list[Path]:
        """Write what is pending, finalize the file and return the files written."""
        if self._closed:
            return []
        self._pending.append(("close", ()))
        self._send()
        self._closed = True
        files = self._expect("closed")  # the file is complete now; the child only has to exit (~20 ms)
        threading.Thread(target=self._process.wait, name="mcap-writer-reaper", daemon=True).start()
        return [Path(p) for p in files]

    def _call(self, call: str, arguments: tuple) -> None:
        if self._closed:
            raise RecordingError("the recording is closed")
        self._pending.append((call, arguments))
        if len(self._pending) >= BATCH:
            self._send()

    def _send(self) -> None:
        if select.select([self._process.stdout], [], [], 0.0)[0]:  # the child failed since the last batch
            self._expect("nothing")
        frame = self._pending[0][1] if self._pending[0][0] == "start" else self._pending
        try:
            pickle.dump(frame, self._process.stdin)
            self._process.stdin.flush()
        except (BrokenPipeError, OSError) as error:
            self._expect("nothing", f"the MCAP writer process ended: {error}")
        self._pending = []

    def _expect(self, kind: str, lost: str = "the MCAP writer process ended unexpectedly") -> Any:
        try:
            reply, value = pickle.load(self._process.stdout)
        except (EOFError, pickle.UnpicklingError):
            reply, value = "error", lost
        if reply != kind:
            self._closed = True
            self._process.kill()
            self._process.wait()
            raise RecordingError(value if reply == "error" else f"unexpected reply '{reply}' from the MCAP writer")
        return value


if __name__ == "__main__":
    replies = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # anything else printed must not corrupt the replies
    serve(sys.stdin.buffer, replies)
