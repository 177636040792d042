"""The tissue's compiled run of steps (``tissue.sequence``) against the general step (``model.data.step`` with
``TissueModel.advance``): the same needle states, wrenches and tissue states, bit for bit, for every axial law,
through the capsule puncture and the bevel's engagement; and the track projection's pruned search against a
brute-force projection."""
import numpy as np
import pytest

from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import simulation_from_parameters
from needle_sim_ros.tissue.tissue_model import TissueModel
from needle_sim_ros.tissue.track import project_on_polyline

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
LAWS = {
    "karnopp": {},
    "none": {"tissue.shaft.axial_model": "none"},
    "insertion_profile": {"tissue.shaft.axial_model": "insertion_profile", "tissue.insertion_profile.enable": True},
    "lugre": {"tissue.shaft.axial_model": "lugre", "tissue.insertion_profile.enable": True},
}


def pose(t: float) -> tuple[list, list]:
    """Inserting at 10 mm/s from t = 0.1 s while swaying 1 mm sideways and rolling the bevel by 20 deg."""
    roll = np.deg2rad(20.0) * np.sin(2.0 * np.pi * t)
    return ([0.01 * max(t - 0.1, 0.0), 1e-3 * np.sin(2.0 * np.pi * t), 0.0],
            [np.sin(0.5 * roll), 0.0, 0.0, np.cos(0.5 * roll)])


def insert(compiled: bool, overrides: dict, monkeypatch, seconds: float = 1.2):
    """The simulator with tissue (entry 6 mm before the needle's tip: 5 mm inserted at the end), driven by poses at
    1 kHz; the general step only unless ``compiled``. Returns the simulation, its records and the number of
    general tissue advances."""
    sim = simulation_from_parameters({**PARAMETERS, "tissue.enable": True, "tissue.entry_point": [0.272, 0.0, 0.0],
                                      **overrides})
    sim.compiled_sequence = compiled
    calls = []
    advance = TissueModel.advance
    monkeypatch.setattr(TissueModel, "advance", lambda *args: calls.append(1) or advance(*args))
    records = []
    for k in range(int(round(seconds * 1e3))):
        sim.offer_pose(k * 1e-3, *pose(k * 1e-3))
        records += sim.advance(k * 1e-3, deterministic=True)
    return sim, records, len(calls)


@pytest.mark.parametrize("law", LAWS)
def test_the_compiled_run_is_the_general_step_bit_for_bit(law, monkeypatch):
    general, general_records, general_advances = insert(False, LAWS[law], monkeypatch)
    compiled, compiled_records, compiled_advances = insert(True, LAWS[law], monkeypatch)
    contact = general.data.force_states[0].contact
    assert contact.punctured and contact.track.length > 4e-3 and contact.at_front  # it cut its way in
    assert general_advances == len(general_records) > 1000 and compiled_advances <= 2  # the paths taken
    for a, b in zip(general_records, compiled_records, strict=True):
        assert a.t == b.t
        np.testing.assert_array_equal(a.wrench.force_base, b.wrench.force_base)
        np.testing.assert_array_equal(a.wrench.torque_base, b.wrench.torque_base)
    for name in ("q", "qd", "qdd", "aux"):
        np.testing.assert_array_equal(getattr(general.state, name), getattr(compiled.state, name))
    assert_same(general.data.force_states, compiled.data.force_states)
    np.testing.assert_array_equal(general.tissue_readout().tip_force, compiled.tissue_readout().tip_force)


def assert_same(a, b, path: str = "force_states") -> None:
    """Equal values all the way down (tuples, objects' attributes, arrays with their dtypes, numbers)."""
    assert type(a) is type(b), path
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), path
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            assert_same(a[key], b[key], f"{path}.{key}")
    elif hasattr(a, "__slots__"):  # the track
        assert_same(a.__reduce__()[1], b.__reduce__()[1], path)
    elif hasattr(a, "__dict__"):
        assert_same(vars(a), vars(b), path)
    else:
        assert a == b or (a != a and b != b), path


def brute_force_projection(vertices: np.ndarray, arc: np.ndarray, end_tangent: np.ndarray, point: np.ndarray):
    """Closest distance and coordinate of a point on the polyline and its continuation, by checking every
    segment with numpy (independent of the compiled search)."""
    end = vertices[-1]
    beyond = max((point - end) @ end_tangent, 0.0)
    candidates = [(np.linalg.norm(point - end - beyond * end_tangent), arc[-1] + beyond)]
    for j in range(len(vertices) - 1):
        a, b = vertices[j], vertices[j + 1]
        length2 = (b - a) @ (b - a)
        fraction = np.clip((point - a) @ (b - a) / length2, 0.0, 1.0) if length2 > 0 else 0.0
        candidates.append((np.linalg.norm(point - a - fraction * (b - a)), arc[j] + fraction * (arc[j + 1] - arc[j])))
    return min(candidates, key=lambda candidate: candidate[0])


def test_the_pruned_track_projection_finds_the_closest_point():
    rng = np.random.default_rng(3)
    for trial in range(150):
        n = int(rng.integers(1, 120))
        steps = rng.normal(size=(n - 1, 3)) * 1e-4 + np.array([1e-4, 0.0, 0.0]) * (trial % 3)
        steps[rng.random(n - 1) < 0.1] = 0.0                    # repeated vertices
        vertices = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(steps, axis=1))])
        end_tangent = rng.normal(size=3)
        end_tangent /= np.linalg.norm(end_tangent)
        points = vertices[rng.integers(0, n, 8)] + rng.normal(size=(8, 3)) * 10.0 ** rng.uniform(-7, -2)
        coordinate, distance = project_on_polyline(vertices, arc, end_tangent, points)
        for k, point in enumerate(points):
            best_distance, best_coordinate = brute_force_projection(vertices, arc, end_tangent, point)
            assert distance[k] == pytest.approx(best_distance, rel=1e-9, abs=1e-15)
            assert coordinate[k] == pytest.approx(best_coordinate, rel=1e-9, abs=1e-12)
