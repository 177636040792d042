"""The simulator's health levels (nodes.diagnostics): each cause raises the level in its window only."""
from needle_sim_ros.nodes.diagnostics import ERROR, OK, WARN, HealthMonitor

RUNNING = dict(started=True, pose_age=0.001, pose_timeout=0.1)


def counters(**changes):
    base = {"steps": 0, "failed_steps": 0, "deadline_misses": 0, "skipped_time_s": 0.0, "rejected_poses": 0}
    return {**base, **changes}


def test_failed_steps_are_an_error_that_clears():
    monitor = HealthMonitor()
    assert monitor.assess(counters(steps=1000), **RUNNING).level == OK
    health = monitor.assess(counters(steps=2000, failed_steps=3), **RUNNING)
    assert health.level == ERROR and "3 step(s) failed" in health.message
    assert monitor.assess(counters(steps=3000, failed_steps=3), **RUNNING).level == OK


def test_warnings_name_their_cause_and_the_worst_level_wins():
    monitor = HealthMonitor()
    health = monitor.assess(counters(steps=1000, rejected_poses=2, failed_steps=1), started=True, pose_age=0.5,
                            pose_timeout=0.1)
    assert health.level == ERROR
    assert "no base pose for 0.50 s" in health.message and "rejected input: 2 poses" in health.message
    assert monitor.assess(counters(steps=2000, rejected_poses=2, failed_steps=1), **RUNNING).level == OK
    assert monitor.assess(counters(), started=False, pose_age=float("inf"), pose_timeout=0.1).level == WARN


def test_deadline_misses_warn_above_one_percent_of_the_steps():
    monitor = HealthMonitor()
    assert monitor.assess(counters(steps=1000, deadline_misses=10), **RUNNING).level == OK
    health = monitor.assess(counters(steps=2000, deadline_misses=30), **RUNNING)
    assert health.level == WARN and "20 of 1000 steps missed their deadline" in health.message
    health = monitor.assess(counters(steps=3000, deadline_misses=30, skipped_time_s=0.2), **RUNNING)
    assert health.level == WARN and "skipped 0.200 s" in health.message
