"""The independent Winkler path-memory reference (reference_winkler.py) against closed forms, its convergence, and the
issue 13 validation case it provides."""
from __future__ import annotations

import numpy as np
import pytest

from reference_winkler import (WinklerNeedle, insert, insertion_depths, plot_tip_deflection, reference_insertion,
                               reference_table, rolled_bevel_force, validation_case)

EI = 0.0207  # N m^2, about the 18 G tube's
K = 2.13e4   # N/m^2, about the Vesic modulus of the case
LAMBDA = (K / (4.0 * EI)) ** 0.25


def _tip(needle: WinklerNeedle, depth: float, cut: float, force: float,
         rest_depth=np.zeros(1), rest=np.zeros((1, 1))) -> tuple[float, float]:
    w, slope = needle.solve(depth, cut, rest_depth, rest, np.array([force]))
    return w[-1, 0], slope[-1, 0]


def test_cantilever_tip_load():
    """No tissue: w(L) = P L^3 / (3 EI), w'(L) = P L^2 / (2 EI) within 0.1 %."""
    length, force = 0.26, 9.3e-3
    w, slope = _tip(WinklerNeedle(length, EI, K, 40), 0.0, 0.0, force)
    assert w == pytest.approx(force * length**3 / (3 * EI), rel=1e-3)
    assert slope == pytest.approx(force * length**2 / (2 * EI), rel=1e-3)


def test_hetenyi_semi_infinite_end_load():
    """Whole beam in tissue at rest positions 0, free end loaded: w0 = 2 P lambda / k, theta0 = 2 P lambda^2 / k
    (Hetenyi), within 0.5 %; the clamp is 12/lambda away (its influence ~ e^-12)."""
    length, force = 12.0 / LAMBDA, 9.3e-3
    w, slope = _tip(WinklerNeedle(length, EI, K, 400), length, length, force)
    assert w == pytest.approx(2 * force * LAMBDA / K, rel=5e-3)
    assert slope == pytest.approx(2 * force * LAMBDA**2 / K, rel=5e-3)


@pytest.mark.parametrize("overhang_lambda", [0.5, 2.0])
def test_uncut_front_carries_no_spring(overhang_lambda: float):
    """The cut front (depth beyond the cut) is a free overhang e on a semi-infinite foundation: from Hetenyi's end
    flexibilities (w, phi) = (2 lambda/k) [[1, lambda], [lambda, 2 lambda^2]] (F, M) with F = P, M = P e,
    w(tip) = P (2 lambda/k + 4 lambda^2 e/k + 4 lambda^3 e^2/k + e^3/(3 EI)), within 0.5 %."""
    overhang, force = overhang_lambda / LAMBDA, 9.3e-3
    length = 12.0 / LAMBDA + overhang
    w, _ = _tip(WinklerNeedle(length, EI, K, 400), length, length - overhang, force)
    expected = force * (2 * LAMBDA / K + 4 * LAMBDA**2 * overhang / K + 4 * LAMBDA**3 * overhang**2 / K
                        + overhang**3 / (3 * EI))
    assert w == pytest.approx(expected, rel=5e-3)


def test_rest_positions_slide_with_depth():
    """Tissue rest positions linear in depth p, y = c0 + c1 p, no load: the tip (p = d) sits on them,
    w = c0 + c1 d, w' = c1, although the surface is at s = L - d, not at the clamp."""
    depth = 12.0 / LAMBDA
    length = depth + 4.0 / LAMBDA
    c0, c1 = 1e-3, 0.02
    w, slope = _tip(WinklerNeedle(length, EI, K, 400), depth, depth, 0.0,
                    np.array([0.0, depth]), np.array([[c0], [c0 + c1 * depth]]))
    assert w == pytest.approx(c0 + c1 * depth, rel=1e-4)
    assert slope == pytest.approx(c1, rel=1e-3)


def test_beam_column_dead_axial_load():
    """Compressive dead load P = P_cr/2 and tip load Q: w(L) = Q (tan(aL) - aL) / (P a), a = sqrt(P/EI)."""
    length, lateral = 0.26, 9.3e-3
    axial = 0.5 * np.pi**2 * EI / (4 * length**2)
    a = np.sqrt(axial / EI)
    w, _ = _tip(WinklerNeedle(length, EI, K, 100, axial), 0.0, 0.0, lateral)
    assert w == pytest.approx(lateral * (np.tan(a * length) - a * length) / (axial * a), rel=1e-3)


def test_beam_column_follower_axial_load():
    """Compressive follower load P (along the tip tangent), aL = 1.5, and tip load Q:
    EI w'''' + P w'' = 0, EI w'''(L) = -Q, so w(L) = Q (sin(aL) - aL cos(aL)) / (P a)."""
    length, lateral = 0.26, 9.3e-3
    a = 1.5 / length
    axial = a**2 * EI
    w, _ = _tip(WinklerNeedle(length, EI, K, 100, axial, follower=True), 0.0, 0.0, lateral)
    assert w == pytest.approx(lateral * (np.sin(a * length) - a * length * np.cos(a * length)) / (axial * a),
                              rel=1e-3)


def test_hetenyi_mesh_convergence():
    """The end-load deflection error against Hetenyi falls as h^4 (Hermite elements): more than 12-fold per mesh
    doubling from h = lambda^-1 on (measured: 3.4e-3, 2.5e-4, 1.6e-5, 1.0e-6)."""
    length, force = 12.0 / LAMBDA, 9.3e-3
    exact = 2 * force * LAMBDA / K
    errors = np.array([abs(_tip(WinklerNeedle(length, EI, K, n), length, length, force)[0] / exact - 1)
                       for n in (12, 24, 48, 96)])
    assert np.all(errors[1:] < errors[:-1] / 12)
    assert errors[-1] < 2e-6


def test_validation_case_parameters():
    """Issue 13 case: Q is the issue's 9.3 mN; k and P match hand evaluations of Vesic's formula and eq. 4
    (I = 1.0349e-13 m^4, EI = 0.020698 N m^2, k = 0.65 (9.55e-6)^(1/12) 85934 = 2.132e4 N/m^2, P = 6.76 mN)."""
    case = validation_case()
    assert case.second_moment == pytest.approx(1.0349e-13, rel=1e-3)
    assert case.winkler_modulus == pytest.approx(2.132e4, rel=2e-3)
    assert case.transverse_bevel_force == pytest.approx(9.32e-3, rel=2e-3)
    assert case.axial_bevel_force == pytest.approx(6.76e-3, rel=2e-3)


def test_validation_case_converged_in_mesh_and_step():
    """The case's tip deflection at 30/60/90 mm changes < 0.2 % from halving the elements and the depth step."""
    case = validation_case()
    coarse = reference_insertion(case, n_elements=200, step=5e-4)
    fine = reference_insertion(case, n_elements=400, step=2.5e-4)
    for depth in (0.03, 0.06, 0.09):
        tips = [run.tip_deflection[np.argmin(np.abs(run.depth - depth)), 0] for run in (coarse, fine)]
        assert tips[0] == pytest.approx(tips[1], rel=2e-3)


def test_roll_180_mirrors_and_90_turns_the_plane():
    """Linear, decoupled directions: a 180 deg roll at depth 0 mirrors the path exactly; a 90 deg roll halfway
    leaves the first direction as if Q stopped there and the second as if Q started there."""
    needle = WinklerNeedle(0.26, EI, K, 100)
    depths = insertion_depths(0.06, 1e-3)
    straight = insert(needle, depths, rolled_bevel_force(9.3e-3))
    mirrored = insert(needle, depths, rolled_bevel_force(9.3e-3, roll_depth=0.0))
    np.testing.assert_allclose(mirrored.tip_deflection, -straight.tip_deflection, atol=1e-15)
    turned = insert(needle, depths, rolled_bevel_force(9.3e-3, roll_depth=0.03, roll=0.5 * np.pi))
    before = insert(needle, depths, lambda d: np.array([9.3e-3 * (d < 0.03)]))
    after = insert(needle, depths, lambda d: np.array([9.3e-3 * (d >= 0.03)]))
    np.testing.assert_allclose(turned.tip_deflection[:, 0], before.tip_deflection[:, 0], atol=1e-12)
    np.testing.assert_allclose(turned.tip_deflection[:, 1], after.tip_deflection[:, 0], atol=1e-12)


def test_bad_depths_are_rejected():
    needle = WinklerNeedle(0.26, EI, K, 20)
    with pytest.raises(ValueError, match="depths"):
        insert(needle, np.array([0.0, 0.02, 0.01]), rolled_bevel_force(1e-3))


def test_reference_table_and_plot(tmp_path):
    """Prints the reference tip deflections at 30/60/90 mm (pytest -s) and writes the Fig. 4-style plot with an
    overlay, atomically."""
    case = validation_case()
    print("\n" + reference_table(case))
    run = reference_insertion(case)
    path = tmp_path / "fig4.png"
    plot_tip_deflection(str(path), run.depth, run.tip_distance,
                        overlays=((run.depth[::10], 1.02 * run.tip_distance[::10], "overlay"),))
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["fig4.png"]
