"""The ``insertion`` scenario as a user drives it: the result's JSON (SI units), the flags, params files."""
import argparse
import json

import numpy as np
import pytest

from needle_sim_ros.model import NeedleProperties
from needle_sim_ros.scenarios import insertion
from needle_sim_ros.scenarios.insertion_motion import InsertionMotion

PROPS = NeedleProperties(0.27, 0.635e-3, 193e9, 8000.0)          # seed 000 needle, with gravity (-z)


@pytest.fixture(scope="module")
def result():
    return insertion.simulate_insertion(PROPS, {}, InsertionMotion((0.02,), 0.006), dt=2e-3, sample_every=10)


def test_result_follows_the_scenario_json_conventions(result):
    n = len(result["insertion_depth_m"])
    for key in ("time_s", "tip_lateral_deflection_m", "tip_position_m", "tip_offset_m", "tip_tangent",
                "base_force_n", "base_torque_nm"):
        assert len(result[key]) == n, key
    depth = np.asarray(result["insertion_depth_m"])
    assert depth[-1] == pytest.approx(0.02, abs=0.2e-3)
    tip = np.asarray(result["tip_position_m"])
    # the lateral deflection is the tip's distance from the entry axis (world x through the base), perpendicular
    np.testing.assert_allclose(result["tip_lateral_deflection_m"], np.hypot(tip[:, 1], tip[:, 2]))
    needle = result["parameters"]["needle"]
    assert needle["inner_radius_m"] == 0.0 and needle["axial_gauss_points"] == 2
    assert result["parameters"]["winkler_modulus_n_m2"] == [2.0e4]
    # the holder pushes the needle in against the tissue: the needle's reaction on the holder points back (-x)
    assert result["base_force_n"][-1][0] < 0
    json.dumps(result, allow_nan=False)                            # strict JSON (an unbounded layer -> "inf")


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    insertion.add_parser(parser.add_subparsers())
    return parser.parse_args(["insertion", *argv])


def test_command_line_writes_json_and_plot_with_the_shipped_tissue_and_a_params_file(tmp_path):
    params = tmp_path / "sim.yaml"
    params.write_text("needle_simulator:\n  ros__parameters:\n    needle.inner_radius: 0.419e-3\n"
                      "    tissue.layers.lateral_stiffness: [3.0e+4]\n    topics.wrench: wrench\n")
    args = parse("--depth", "0.004", "--retract-to", "0.002", "--roll-deg", "90", "--spin-rate", "12.566",
                 "--duty-cycle", "0.5", "--dt", "0.002", "--params", str(params),
                 "--json", str(tmp_path / "r.json"), "--plot", str(tmp_path / "r.png"))
    assert insertion.run(args) == 0
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["parameters"]["needle"]["inner_radius_m"] == pytest.approx(0.419e-3)
    assert result["parameters"]["winkler_modulus_n_m2"] == [3.0e4]
    # the shipped tissue config (found through the package share directory) is in force: bevel side +y
    assert result["parameters"]["tissue"]["tissue.bevel_tip.side"] == [0.0, 1.0, 0.0]
    assert result["motion"] == {"depths_m": [0.004, 0.002], "speed_m_s": 0.006, "gap_m": 0.002,
                                "roll_rad": pytest.approx(np.pi / 2), "spin_rate_rad_s": 12.566, "duty_cycle": 0.5}
    assert result["insertion_depth_m"][-1] == pytest.approx(0.002, abs=0.2e-3)
    assert (tmp_path / "r.png").stat().st_size > 1000


def test_bad_motion_is_a_clear_error():
    for bad in ({"waypoints": (0.09,), "speed": 0.0}, {"waypoints": (-0.01,), "speed": 0.006},
                {"waypoints": (0.09,), "speed": 0.006, "duty_cycle": 0.5},
                {"waypoints": (0.09,), "speed": 0.006, "duty_cycle": 1.5, "spin_rate": 1.0},
                # before: a NaN roll ended in a StaticSolveFailed traceback, a NaN spin rate was accepted
                {"waypoints": (0.09,), "speed": 0.006, "roll": float("nan")},
                {"waypoints": (0.09,), "speed": 0.006, "spin_rate": float("nan")},
                {"waypoints": (0.09,), "speed": 0.006, "duty_cycle": float("nan"), "spin_rate": 1.0}):
        with pytest.raises(ValueError):
            InsertionMotion(**bad)
