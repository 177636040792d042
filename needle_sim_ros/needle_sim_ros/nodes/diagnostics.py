"""Health of the needle simulator for ``/diagnostics``: a level and a message from what happened since the last report.

Each report looks at the counters' increase over its window, so a level lasts as long as its cause:
- ERROR: steps failed (the needle was reset to the straight state);
- WARN: no base pose yet, the pose input lost (the last pose held), inputs rejected (poses, twists, tip loads),
  wall-clock deadlines missed or simulated time skipped to catch up;
- OK otherwise.
In simulated time (``use_sim_time``) there is no deadline: several steps per tick are catch-up (``catch_up_steps``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels (bytes 0, 1, 2)
DEADLINE_MISS_FRACTION = 0.01  # WARN when more than this fraction of a window's wall-clock steps missed


@dataclass(frozen=True)
class Health:
    level: int
    message: str


@dataclass
class HealthMonitor:
    """Turns cumulative counters into a per-window :class:`Health` (see the module docstring)."""

    previous: dict[str, float] = field(default_factory=dict)

    def increase(self, counters: dict[str, float], key: str) -> float:
        return counters.get(key, 0) - self.previous.get(key, 0)

    def assess(self, counters: dict[str, float], started: bool, pose_age: float, pose_timeout: float,
               active: bool = True) -> Health:
        """``counters``: cumulative ``steps``, ``failed_steps``, ``deadline_misses``, ``skipped_time_s`` and
        ``rejected_<input>`` counts; ``pose_age`` [s] of the newest base pose."""
        causes: list[tuple[int, str]] = []
        failed = self.increase(counters, "failed_steps")
        if failed > 0:
            causes.append((ERROR, f"{failed:.0f} step(s) failed: needle reset to the straight state"))
        if not active:
            causes.append((OK, "inactive (lifecycle): holding, not integrating"))
        elif not started:
            causes.append((WARN, "waiting for the first base pose"))
        elif pose_age > pose_timeout:
            causes.append((WARN, f"no base pose for {pose_age:.2f} s: holding the last pose"))
        rejected = {key[len("rejected_"):]: count for key in sorted(counters)
                    if key.startswith("rejected_") and (count := self.increase(counters, key)) > 0}
        if rejected:
            causes.append((WARN, "rejected input: " + ", ".join(f"{n:.0f} {name.replace('_', ' ')}"
                                                                  for name, n in rejected.items())))
        steps, misses = self.increase(counters, "steps"), self.increase(counters, "deadline_misses")
        if misses > DEADLINE_MISS_FRACTION * max(steps, 1):
            causes.append((WARN, f"{misses:.0f} of {steps:.0f} steps missed their deadline"))
        skipped = self.increase(counters, "skipped_time_s")
        if skipped > 0:
            causes.append((WARN, f"fell behind: skipped {skipped:.3f} s of simulated time"))
        self.previous = dict(counters)
        if not causes:
            return Health(OK, "running")
        level = max(level for level, _ in causes)
        return Health(level, "; ".join(message for _, message in causes))
