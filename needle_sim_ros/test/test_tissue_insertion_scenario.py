"""The ``insertion`` scenario: bevel-tip steering in a homogeneous block (issue #5 validation)."""
import argparse
import json

import numpy as np
import pytest

from needle_sim_ros.model import NeedleProperties
from needle_sim_ros.scenarios import insertion

PROPS = NeedleProperties(0.27, 0.635e-3, 193e9, 8000.0)          # seed 000 needle, with gravity (-z)
BEVEL_SIDE_Y = {"tissue.bevel_tip.side": [0.0, 1.0, 0.0]}        # horizontal bevel: gravity does not bias it


@pytest.fixture(scope="module")
def runs():
    # Seed 001 Sec. V-D: 90 mm at 6 mm/s.  dt = 2 ms (the 1 ms loop is benchmarked in bench/bench_tissue.py)
    # keeps the two runs within the suite's time budget; the deflection changes < 1 % between the two steps.
    return {roll: insertion.simulate_insertion(PROPS, BEVEL_SIDE_Y, speed=0.006, depth=0.09, roll=roll, dt=2e-3,
                                               sample_every=50)
            for roll in (0.0, np.pi)}


def test_bevel_tip_needle_bends_toward_the_bevel_and_axial_rotation_reverses_it(runs):
    lateral = {roll: np.array([s["tip_deflection_m"][0] for s in run["samples"]]) for roll, run in runs.items()}
    depth = np.array([s["insertion_depth_m"] for s in runs[0.0]["samples"]])
    assert depth[-1] == pytest.approx(0.09, abs=0.5e-3)
    deep = depth > 0.03
    assert np.all(lateral[0.0][deep] > 0)                          # toward +y, the bevel side
    assert np.all(lateral[np.pi][deep] < 0)                        # rolled 180 deg: toward -y
    # mirror symmetry about the x-z plane (gravity acts along z): equal and opposite to 1 %
    np.testing.assert_allclose(lateral[np.pi], -lateral[0.0], rtol=0.01, atol=1e-7)
    # the deflection grows with depth once the tissue, not the clamp, holds the needle (track curvature)
    assert lateral[0.0][-1] > 1.5 * lateral[0.0][np.searchsorted(depth, 0.045)]


def test_result_follows_the_scenario_json_conventions(runs, tmp_path):
    result = runs[0.0]
    for key in ("elements", "material", "dt_s", "simulated_time_s", "integration_wall_time_s", "wall_time_s",
                "samples"):
        assert key in result
    assert set(result["material"]) == {"youngs_modulus_pa", "density_kg_m3", "radius_m", "length_m", "gravity_m_s2"}
    sample = result["samples"][-1]
    assert len(sample["base_force_n"]) == 3 and len(sample["base_torque_nm"]) == 3
    # the holder pushes the needle in against the tissue: the needle's reaction on the holder points back (-x)
    assert sample["base_force_n"][0] < 0
    json.dumps(result, allow_nan=False)                            # strict JSON (an unbounded layer -> "inf")


def test_command_line_writes_json_and_plot(tmp_path):
    parser = argparse.ArgumentParser()
    insertion.add_parser(parser.add_subparsers())
    args = parser.parse_args(["insertion", "--depth", "0.004", "--dt", "0.002", "--json", str(tmp_path / "r.json"),
                              "--plot", str(tmp_path / "r.png")])
    assert insertion.run(args) == 0
    assert json.loads((tmp_path / "r.json").read_text())["samples"]
    assert (tmp_path / "r.png").stat().st_size > 1000
