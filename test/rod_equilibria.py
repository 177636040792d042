"""Needles along the epipolar lines that are elastic-rod equilibria (issue 39): the seed 000 needle (needle_sim_ros
defaults, 30 elements) clamped at the origin, under its own weight and a load at the tip, from the simulator's
static solve (``needle_sim_ros.model.solve_static``). The rig's baseline runs along world z, so each shape ends or
runs along z. Stored for needle_vision's tests as ``needle_vision/test/data/<name>.npy`` (1081 points, 0.25 mm
apart); run this file to regenerate them. Suite-level: it composes both packages (needle_vision's tests only read
the stored shapes)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.optimize import brentq, newton
from scipy.spatial.transform import Rotation

DATA = Path(__file__).resolve().parents[1] / "needle_vision" / "test" / "data"
SAMPLES = 1081
ELEMENTS = 30
Z = np.array([0.0, 0.0, 1.0])


def _solver():
    """``solve(rotation, tip_force, tip_gradient_force) -> (points, tangents)``: the equilibrium's centerline."""
    from needle_sim_ros.model import BaseMotion, Gravity, NodalLoad, build_model, centerline, load_needle_config, \
        solve_static

    props, build, _ = load_needle_config({})
    model = build_model(props, **{**build, "n_elements": ELEMENTS})

    def solve(rotation: np.ndarray, force: np.ndarray, gradient: np.ndarray = np.zeros(3)):
        base = BaseMotion((0.0, 0.0, 0.0), Rotation.from_matrix(rotation).as_quat())
        state = solve_static(model, base, [Gravity(), NodalLoad(-1, force, gradient)], load_steps=8).state
        line = centerline(model, state.q, SAMPLES)
        return line.points, line.tangents
    return solve


def _curl(solve, yaw: float, up: float, backward_deg: float, gradient: float) -> np.ndarray:
    """Curls in the vertical plane at ``yaw`` (towards the cameras) until the tip points along ``up`` z: a tip force
    ``backward_deg`` behind the vertical, its size found so that the tip tangent has no horizontal part, and a
    gradient force ``gradient`` [N m] against the base direction (a tip moment: a shorter straight tail)."""
    rotation = Rotation.from_euler("z", yaw).as_matrix()
    ahead = rotation[:, 0]
    direction = -np.sin(np.radians(backward_deg)) * ahead + up * np.cos(np.radians(backward_deg)) * Z
    shape = lambda size: solve(rotation, size * direction, -gradient * ahead)  # noqa: E731
    size = brentq(lambda size: shape(size)[1][-1] @ ahead, 0.0, 5.0, xtol=1e-10)
    return shape(size)[0]


def _s(solve, yaw: float, pitch_deg: float) -> np.ndarray:
    """An S in the vertical plane at ``yaw``: the holder pitched ``pitch_deg`` down, a tip shear force across the
    holder's axis and a gradient force turning the tip back to the holder's direction (a guided beam), the force's
    size found so that the S's middle, its inflection, points straight down (along -z)."""
    rotation = Rotation.from_euler("z", yaw).as_matrix() @ Rotation.from_euler("y", pitch_deg, degrees=True).as_matrix()
    across, ahead = rotation[:, 2], Rotation.from_euler("z", yaw).as_matrix()[:, 0]
    angle = lambda tangents: np.arctan2(tangents @ Z, tangents @ ahead)  # noqa: E731
    moment = [0.3]

    def guided(size: float):
        moment[0] = newton(lambda m: angle(solve(rotation, -size * across, m * across)[1])[-1]
                           + np.radians(pitch_deg), moment[0], x1=1.05 * moment[0], tol=1e-12)
        return solve(rotation, -size * across, moment[0] * across)
    size = brentq(lambda size: np.degrees(angle(guided(size)[1])).min() + 90.0, 4.0, 5.0, xtol=1e-10)
    return guided(size)[0]


def equilibria() -> dict[str, np.ndarray]:
    """The shapes, solved now (needs needle_sim_ros; ~10 s once its kernels are compiled)."""
    solve = _solver()
    return {
        # Curls down in a plane turned 0.3 rad towards the cameras until its tip hangs along -z.
        "rod_curl_down": _curl(solve, 0.3, -1.0, 35.0, 0.0),
        # Curls up, 0.4 rad towards the cameras, until its tip points along +z (a tip moment keeps it in view).
        "rod_curl_up": _curl(solve, 0.4, 1.0, 35.0, 0.12),
        # An S whose middle runs along -z.
        "rod_s": _s(solve, 0.3, 30.0),
    }


if __name__ == "__main__":
    DATA.mkdir(exist_ok=True)
    for name, points in equilibria().items():
        np.save(DATA / f"{name}.npy", points)
