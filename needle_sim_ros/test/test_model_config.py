"""Needle configuration from ROS 2 params files (config/needle_simulator.yaml and variants)."""

import pytest
import yaml

from needle_common.package_files import share_file

from needle_sim_ros.model import Fixture, Integrator, build_model, load_needle_config, needle_parameters

CONFIG = share_file("needle_sim_ros", "config/needle_simulator.yaml")  # as installed


def test_shipped_config_describes_the_seed_needle():
    props, build, integrator = load_needle_config(CONFIG)
    assert (props.length, props.radius, props.youngs_modulus, props.density) == (0.27, 0.635e-3, 193e9, 8000.0)
    assert build["n_elements"] == 10 and build["axial_gauss"] == 2 and build["bending_gauss"] == 3   # locking-free
    assert needle_parameters(CONFIG)["integrator.dt"] == 1e-3
    model = build_model(props, **build)
    Integrator(model, **integrator)  # the kwargs fit the constructors


def test_params_file_format_and_overrides(tmp_path):
    text = {"/**": {"ros__parameters": {
        "needle": {"elements": 6, "gravity": [0.0, 0.0, 0.0]},
        "damping": {"rayleigh_alpha": 2.0},
        "integrator": {"method": "hht", "rho_inf": 0.9},
        "fixtures": {"intervals": [0.18, 0.27], "frame": "base"},
        "topics": {"wrench": "wrench"}}}}  # other groups (the node's) are ignored
    path = tmp_path / "needle.yaml"
    path.write_text(yaml.safe_dump(text))
    props, build, integrator = load_needle_config(path)
    assert props.gravity == (0.0, 0.0, 0.0) and build["n_elements"] == 6 and build["rayleigh_alpha"] == 2.0
    assert integrator["method"] == "hht" and integrator["rho_inf"] == 0.9
    (fixture,) = build["fixtures"]
    assert isinstance(fixture, Fixture) and fixture.interval == (0.18, 0.27) and fixture.frame == "base"
    # the default mesh for a clamp: one element over it, so the base node and the nodes at 0.18 and 0.27 m
    assert build_model(props, **build).partition.constrained_dofs.size == 6 * 3
    # a plain nested or flat dict works as well
    assert load_needle_config({"needle": {"elements": 3}})[1]["n_elements"] == 3
    assert load_needle_config({"needle.elements": 4})[1]["n_elements"] == 4


def test_bad_config_is_reported_by_name(tmp_path):
    with pytest.raises(ValueError, match="needle.lenght"):
        load_needle_config({"needle": {"lenght": 0.3}})
    with pytest.raises(ValueError, match="integrator.method"):
        load_needle_config({"integrator": {"method": "euler"}})
    with pytest.raises(ValueError, match="radius"):
        load_needle_config({"needle": {"radius": -1.0}})
    with pytest.raises(ValueError, match="fixtures.intervals"):
        load_needle_config({"fixtures": {"intervals": [0.1]}})
    with pytest.raises(FileNotFoundError):
        load_needle_config(tmp_path / "missing.yaml")
