"""The ``needle_scenario`` command line: JSON contents and figures of the static, pitch and free_vibration
scenarios (short runs)."""
import json

import numpy as np
import pytest

from needle_sim_ros.scenarios.cli import main


def test_static_single_and_sweep(tmp_path):
    out = tmp_path / "static.json"
    assert main(["static", "--tip-mass", "0.08", "--elements", "10", "--json", str(out),
                 "--plot", str(tmp_path / "static.png")]) == 0
    result = json.loads(out.read_text())
    for key in ("elements", "material", "tip_mass_kg", "tip_position_m", "base_wrench", "centerline_m",
                "wall_time_s"):
        assert key in result
    assert set(result["material"]) == {"youngs_modulus_pa", "density_kg_m3", "radius_m", "inner_radius_m", "length_m",
                                       "gravity_m_s2"}
    tip = np.array(result["tip_position_m"])
    assert 0.2 < tip[0] < 0.23 and -0.15 < tip[2] < -0.14  # seed 000 Fig. 7 range at 80 g (elastica: 217, -146 mm)
    weight = 9.81 * (0.08 + result["material"]["density_kg_m3"] * np.pi * 0.635e-3**2 * 0.27)
    assert result["base_wrench"]["force_n"][2] == pytest.approx(-weight, rel=1e-9)  # the holder carries it all
    assert np.allclose(result["centerline_m"][-1], tip) and (tmp_path / "static.png").stat().st_size > 0

    sweep = tmp_path / "sweep.json"
    assert main(["static", "--tip-mass", "0", "0.04", "0.08", "--elements", "6", "--json", str(sweep)]) == 0
    results = json.loads(sweep.read_text())["results"]
    assert [r["tip_mass_kg"] for r in results] == [0.0, 0.04, 0.08]
    assert np.all(np.diff([r["tip_position_m"][2] for r in results]) < 0)


def test_pitch_time_series(tmp_path):
    out = tmp_path / "pitch.json"
    assert main(["pitch", "--periods", "0.1", "--dt", "0.002", "--elements", "5", "--sample-interval", "0.1",
                 "--json", str(out), "--plot", str(tmp_path / "pitch.png")]) == 0
    result = json.loads(out.read_text())
    for key in ("dt_s", "simulated_time_s", "integration_wall_time_s", "samples", "tip_position_m", "base_wrench"):
        assert key in result
    assert result["simulated_time_s"] == pytest.approx(0.5) and len(result["samples"]) == 6
    # the clamped tip stays where it was clamped (world frame)
    assert np.allclose(result["samples"][-1]["centerline_world_m"][-1], [0.27, 0.0, 0.0], atol=1e-12)
    assert (tmp_path / "pitch.png").stat().st_size > 0


def test_free_vibration_energy_series(tmp_path):
    out = tmp_path / "release.json"
    assert main(["free_vibration", "--duration", "0.05", "--elements", "4", "--rho-inf", "0.95", "--beta", "0",
                 "--json", str(out), "--plot", str(tmp_path / "release.png")]) == 0
    samples = json.loads(out.read_text())["samples"]
    total = np.array([s["total_energy_j"] for s in samples])
    released = samples[0]["elastic_energy_j"] - samples[-1]["elastic_energy_j"]
    assert samples[0]["kinetic_energy_j"] == 0.0 and samples[-1]["kinetic_energy_j"] > 0.0
    # no Rayleigh and little numerical damping: the total energy (incl. gravity) stays within 1 % of the released
    # energy (measured 0.1 % in 50 ms)
    assert np.abs(total - total[0]).max() < 1e-2 * abs(released) + 1e-12


def test_bad_arguments_give_an_error_code(capsys):
    assert main(["static", "--tip-mass", "-0.1"]) == 2
    assert "tip-mass" in capsys.readouterr().err
    # a load far beyond what the model resolves (before: a StaticSolveFailed traceback, exit 1)
    assert main(["static", "--tip-mass", "1e300"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the model found no solution for these inputs" in err


@pytest.mark.parametrize("option", ["--json", "--plot"])
def test_unwritable_outputs_are_refused_before_the_run(tmp_path, capsys, option):
    """A folder as the output, or a file in the way of its folder: exit 2 naming the option, before simulating."""
    (tmp_path / "a_file").write_text("")
    for target in (tmp_path, tmp_path / "a_file" / "out.json"):
        assert main(["free_vibration", "--duration", "100", option, str(target)]) == 2  # 100 s: would take minutes
        assert f"error: {option} '{target}'" in capsys.readouterr().err


def test_a_failed_write_leaves_no_file(tmp_path):
    from needle_common.output_files import write_atomically

    target = tmp_path / "result.json"
    target.write_text("old")

    def failing(path):
        path.write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError):
        write_atomically(target, failing)
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["result.json"]
