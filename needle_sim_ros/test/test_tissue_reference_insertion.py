"""Issue #13: the dynamic ANCF insertion against the independent reference (reference_winkler: a quasi-static
Euler-Bernoulli beam on a Winkler foundation with path memory, Hermite elements, scipy.sparse; it shares no code
with the ANCF needle and is validated against Hetenyi's and the cantilever's closed forms in
test_reference_winkler.py).

Case: 18 G brachytherapy tube (OD 1.27 mm, ID 0.838 mm), 0.26 m, E 200 GPa, no gravity, in seed 001's phantom
(Vesic's Winkler modulus for E 76 kPa, nu 0.34), bevel forces of seed 001 eqs. 4-5 (K_T 9.42e3 N/m^2,
beta/lambda 0.2, lambda 30 deg), 6 mm/s to 90 mm, no shaft friction (the reference is a linear beam without
axial load).
"""
import numpy as np
import pytest
from reference_winkler import plot_tip_deflection, reference_insertion, validation_case

from needle_sim_ros.model import NeedleProperties
from needle_sim_ros.scenarios.insertion import simulate_insertion
from needle_sim_ros.scenarios.insertion_motion import InsertionMotion

CASE = validation_case()


def ancf_insertion(roll_changes=()) -> dict:
    props = NeedleProperties(CASE.length, 0.5 * CASE.outer_diameter, CASE.youngs_modulus, 8000.0,
                             gravity=(0.0, 0.0, 0.0), inner_radius=0.5 * CASE.inner_diameter)
    tissue = {"tissue.layers.lateral_stiffness": [CASE.winkler_modulus], "tissue.layers.tip_stiffness": [9.42e3],
              "tissue.shaft.axial_model": "none", "tissue.bevel_tip.side": [0.0, 1.0, 0.0],
              "tissue.bevel_tip.bevel_angle": CASE.bevel_angle, "tissue.bevel_tip.acting_fraction": 0.2}
    motion = InsertionMotion((CASE.final_depth,), CASE.insertion_speed, roll_changes=roll_changes)
    return simulate_insertion(props, tissue, motion, dt=1e-3, sample_every=20)


@pytest.fixture(scope="module")
def reference():
    return reference_insertion(CASE)


def test_ancf_tip_deflection_matches_the_independent_winkler_reference(reference, tmp_path):
    result = ancf_insertion()
    depth = np.asarray(result["insertion_depth_m"])
    deflection = np.asarray(result["tip_lateral_deflection_m"])
    checks = (0.03, 0.06, 0.09)
    ancf = np.interp(checks, depth, deflection)
    truth = np.interp(checks, reference.depth, reference.tip_distance)
    print("depth [mm], ANCF, reference [mm]:", [(1e3 * d, round(1e3 * a, 4), round(1e3 * r, 4))
                                                 for d, a, r in zip(checks, ancf, truth)])
    assert result["parameters"]["needle"]["inner_radius_m"] == pytest.approx(0.419e-3)
    assert np.all(np.abs(ancf - truth) <= 0.05 * truth), (ancf, truth)
    plot_tip_deflection(str(tmp_path / "fig4.png"), reference.depth, reference.tip_distance,
                        overlays=((depth, deflection, "ANCF (dynamic, 10 elements)"),))
    assert (tmp_path / "fig4.png").stat().st_size > 1000
