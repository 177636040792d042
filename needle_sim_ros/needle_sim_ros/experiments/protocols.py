"""The sample experiments (seed 000, Sec. III, and a tissue insertion): base motion, loads and sensor schedules.

Each :class:`Experiment` gives the motion of the clamp point A (world frame, exact velocity and acceleration), the
tip loads, the clamp and the sensors' sample times; it drives both :mod:`.ground_truth` and :mod:`.make_bags`.
World frame as in ``needle_vision.render.default_rig()``: A at the origin, the undeformed needle along +x, z up, the
cameras looking from +y. Each experiment's ``description`` and bags/README.md describe it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from needle_sim_ros.model import BaseMotion

G = 9.81  # [m/s^2]
NEEDLE_LENGTH = 0.27  # [m] seed 000, Sec. III
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def cosine_ramp(t: float, start: float, duration: float) -> tuple[float, float, float]:
    """Smooth step from 0 to 1 over [start, start + duration]: value, first and second time derivative."""
    x = np.clip((t - start) / duration, 0.0, 1.0)
    inside = 0.0 < x < 1.0
    w = np.pi / duration
    return (0.5 * (1.0 - np.cos(np.pi * x)), 0.5 * w * np.sin(np.pi * x) if inside else 0.0,
            0.5 * w * w * np.cos(np.pi * x) if inside else 0.0)


@dataclass(frozen=True)
class FixedBase:
    """The base at rest at the world origin, needle along +x."""

    def __call__(self, t: float) -> BaseMotion:
        return BaseMotion(np.zeros(3), IDENTITY)


@dataclass(frozen=True)
class PitchOscillation:
    """theta(t) = amplitude (1 - cos 2 pi f (t - start)) about the base's y axis through A for one period from
    ``start``, at rest before and after; angular velocity and acceleration are exact."""

    amplitude: float  # [rad]
    frequency: float  # [Hz]
    start: float  # [s]

    def angle(self, t: float) -> tuple[float, float, float]:
        period = 1.0 / self.frequency
        if not self.start <= t <= self.start + period:
            return 0.0, 0.0, 0.0
        w = 2.0 * np.pi * self.frequency
        phase = w * (t - self.start)
        return (self.amplitude * (1.0 - np.cos(phase)), self.amplitude * w * np.sin(phase),
                self.amplitude * w * w * np.cos(phase))

    def __call__(self, t: float) -> BaseMotion:
        theta, rate, acceleration = self.angle(t)
        orientation = np.array([0.0, np.sin(0.5 * theta), 0.0, np.cos(0.5 * theta)])
        return BaseMotion(np.zeros(3), orientation, np.zeros(3), np.array([0.0, rate, 0.0]),
                          np.zeros(3), np.array([0.0, acceleration, 0.0]))


@dataclass(frozen=True)
class LinearInsertion:
    """Travel ``distance`` along +x from ``start``: the speed ramps up to ``speed`` over ``ramp`` seconds (cosine),
    stays, and ramps down so that the base stops after exactly ``distance``."""

    speed: float  # [m/s]
    distance: float  # [m]
    start: float  # [s]
    ramp: float  # [s]

    @property
    def end(self) -> float:
        return self.start + self.distance / self.speed + self.ramp  # the two ramps together lose one ramp's travel

    def _travel(self, t: float) -> tuple[float, float, float]:
        """Position, velocity and acceleration along x: v(t) = speed (ramp_up(t) - ramp_down(t)), x its integral."""
        def ramp_integral(t0: float) -> float:
            x = np.clip(t - t0, 0.0, self.ramp)
            return 0.5 * (x - self.ramp / np.pi * np.sin(np.pi * x / self.ramp)) + max(t - t0 - self.ramp, 0.0)

        down = self.end - self.ramp
        up, down_ramp = cosine_ramp(t, self.start, self.ramp), cosine_ramp(t, down, self.ramp)
        return (self.speed * (ramp_integral(self.start) - ramp_integral(down)), self.speed * (up[0] - down_ramp[0]),
                self.speed * (up[1] - down_ramp[1]))

    def __call__(self, t: float) -> BaseMotion:
        x, v, a = self._travel(t)
        return BaseMotion(np.array([x, 0.0, 0.0]), IDENTITY, np.array([v, 0.0, 0.0]), np.zeros(3),
                          np.array([a, 0.0, 0.0]), np.zeros(3))


@dataclass(frozen=True)
class TipWeights:
    """Weights hung on the tip one after another: level k (mass ``masses[k]`` [kg]) is reached by a cosine ramp
    starting at ``settle + (k - 1) * (ramp + hold)``; the world force on the tip is (0, 0, -g m(t))."""

    masses: tuple[float, ...]  # [kg], masses[0] is on the tip from the start
    settle: float  # [s] before the first added weight
    ramp: float  # [s]
    hold: float  # [s]

    def mass(self, t: float) -> float:
        mass = self.masses[0]
        for k in range(1, len(self.masses)):
            value, _, _ = cosine_ramp(t, self.settle + (k - 1) * (self.ramp + self.hold), self.ramp)
            mass += (self.masses[k] - self.masses[k - 1]) * value
        return mass

    def __call__(self, t: float) -> np.ndarray:
        return np.array([0.0, 0.0, -G * self.mass(t)])

    @property
    def hold_ends(self) -> tuple[float, ...]:
        """End of each level's hold [s] (the first level: end of the settling time)."""
        return tuple(self.settle + k * (self.ramp + self.hold) for k in range(len(self.masses)))


def no_tip_force(t: float) -> np.ndarray:
    return np.zeros(3)


@dataclass(frozen=True)
class RolledInsertion:
    """A ``LinearInsertion`` whose base rolls about its axis (world x) by ``roll`` [rad] with a cosine ramp over
    [roll_start, roll_start + roll_duration]: the bevel turns with it (exact angular velocity and acceleration)."""

    insertion: LinearInsertion
    roll: float  # [rad]
    roll_start: float  # [s]
    roll_duration: float  # [s]

    @property
    def end(self) -> float:
        return max(self.insertion.end, self.roll_start + self.roll_duration)

    def __call__(self, t: float) -> BaseMotion:
        travel = self.insertion(t)
        value, rate, acceleration = cosine_ramp(t, self.roll_start, self.roll_duration)
        angle = self.roll * value
        orientation = np.array([np.sin(0.5 * angle), 0.0, 0.0, np.cos(0.5 * angle)])
        return BaseMotion(travel.position, orientation, travel.linear_velocity, np.array([self.roll * rate, 0, 0]),
                          travel.linear_acceleration, np.array([self.roll * acceleration, 0.0, 0.0]))


@dataclass(frozen=True)
class Experiment:
    """One sample bag: robot motion, loads, fixtures and sensor schedules (times [s] from the bag start)."""

    name: str
    description: str
    duration: float
    base: Callable[[float], BaseMotion]
    tip_force: Callable[[float], np.ndarray] = no_tip_force
    tip_load_rate: float = 0.0  # [Hz] of the tip_load topic; 0: no topic
    clamp_interval: tuple[float, float] | None = None  # [m]
    tissue: bool = False
    start_in_equilibrium: bool = True  # the real needle hangs at rest when the recording starts
    pose_rate: float = 200.0  # [Hz]
    frame_times: tuple[float, ...] = ()  # stereo pairs with the needle
    background_time: float | None = None  # needle-free stereo pair (recorded before the needle was mounted)
    shape_sensor_rate: float = 0.0  # [Hz] of a fibre-Bragg-grating shape sensor; 0: none

    @property
    def has_images(self) -> bool:
        return bool(self.frame_times)


def static_tip_load() -> Experiment:
    weights = TipWeights(masses=(0.0, 0.02, 0.04, 0.06, 0.08), settle=1.5, ramp=0.5, hold=1.0)
    return Experiment(
        name="static_tip_load",
        description="seed 000 Fig. 7: base fixed, 0-80 g hung on the tip in 20 g steps (each added over 0.5 s, "
                    "held 1 s); one stereo pair at the end of each hold",
        duration=weights.hold_ends[-1] + 0.2, base=FixedBase(), tip_force=weights, tip_load_rate=50.0,
        frame_times=weights.hold_ends, background_time=0.0)


def dynamic_pitch() -> Experiment:
    pitch = PitchOscillation(amplitude=np.radians(5.0), frequency=0.2, start=1.0)
    frames = tuple(np.round(np.arange(1.5, 6.0 + 1e-9, 0.5), 6))
    return Experiment(
        name="dynamic_pitch",
        description="seed 000 Fig. 8: distal 40 % clamped, base pitching about its y axis through A by "
                    "5°(1 - cos 2 pi 0.2 Hz t) (10° range) for one period after 1 s at rest; stereo pairs at 2 fps",
        duration=6.2, base=pitch, clamp_interval=(0.6 * NEEDLE_LENGTH, NEEDLE_LENGTH), frame_times=frames,
        background_time=0.0)


def insertion() -> Experiment:
    motion = LinearInsertion(speed=0.01, distance=0.04, start=1.0, ramp=0.5)
    return Experiment(
        name="insertion",
        description="insertion into the default tissue block (surface 10 mm in front of the tip, needle_sim_ros."
                    "tissue defaults) at 10 mm/s, 40 mm after 1 s at rest; FBG shape sensor at 20 Hz, no images",
        duration=round(motion.end + 0.5, 6), base=motion, tissue=True, shape_sensor_rate=20.0)


def steering_insertion() -> Experiment:
    travel = LinearInsertion(speed=0.006, distance=0.06, start=1.0, ramp=0.5)
    halfway = travel.start + 0.5 * (travel.end - travel.start)
    motion = RolledInsertion(travel, roll=np.pi, roll_start=halfway - 0.5, roll_duration=1.0)
    return Experiment(
        name="steering_insertion",
        description="bevel-tip steering: insertion into the default tissue block at 6 mm/s, 60 mm after 1 s at "
                    "rest, the base rolled by 180° over 1 s halfway (the path bends back); FBG shape sensor at "
                    "20 Hz, no images",
        duration=round(motion.end + 0.5, 6), base=motion, tissue=True, shape_sensor_rate=20.0)


EXPERIMENTS: dict[str, Callable[[], Experiment]] = {
    "static_tip_load": static_tip_load, "dynamic_pitch": dynamic_pitch, "insertion": insertion,
    "steering_insertion": steering_insertion}
