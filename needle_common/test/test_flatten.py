"""The one flattening of nested parameters into dotted names, loose (the model's and tissue's configuration) and
checked as rcl checks a params file (the loader), against hand-written expectations."""
import pytest

import yaml

from needle_common.parameters import ParameterError, flatten_tree, parameter_tree, params_file_text

NESTED = {"needle": {"length": 0.2, "gravity": [0.0, 0.0, -9.81]}, "tissue": {"layers": {"thickness": [0.01]}},
          "topic": "base_pose"}
FLAT = {"needle.length": 0.2, "needle.gravity": [0.0, 0.0, -9.81], "tissue.layers.thickness": [0.01],
        "topic": "base_pose"}


def test_nested_names_become_dotted_names():
    assert flatten_tree(NESTED) == FLAT
    assert flatten_tree(NESTED, lambda name: name) == FLAT  # valid values pass the check unchanged
    assert flatten_tree({"a": {}}) == {}  # loose: an empty group holds nothing


def test_a_written_params_file_nests_the_dotted_names_and_reads_back_as_written():
    text = params_file_text({"needle_compare": {**FLAT, "pair": (1.0, 2.0)}, "needle_stereo": {"a.b": True}})
    assert yaml.safe_load(text) == {"needle_compare": {"ros__parameters": {**NESTED, "pair": [1.0, 2.0]}},
                                    "needle_stereo": {"ros__parameters": {"a": {"b": True}}}}
    assert parameter_tree(yaml.safe_load(text)) == {**FLAT, "pair": [1.0, 2.0], "a.b": True}


@pytest.mark.parametrize("tree, message", [
    ({"a": {"b": {}}}, "a.b: empty mapping has no value"),
    ({"a": None}, "a: no value (null)"),
    ({"a": [1, None]}, "a: no value (null)"),
    ({"a": [1, 2.0]}, "a = [1, 2.0]: a list must hold one type, not float and int (write 1.0, not 1)"),
    ({"a": [{"b": 1}]}, "a: lists may hold only numbers, strings or booleans, not dict"),
])
def test_the_checked_flattening_refuses_what_rcl_refuses(tree, message):
    with pytest.raises(ParameterError) as error:
        flatten_tree(tree, lambda name: name)
    assert str(error.value) == message


def test_a_params_file_merges_its_sections_in_file_order(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text("/**:\n  ros__parameters:\n    needle: {length: 0.2, elements: 10}\n"
                    "needle_simulator:\n  ros__parameters:\n    needle:\n      elements: 12\n"
                    "      youngs_modulus: 1e9\n")
    # rcl's reading: '1e9' is a float (YAML 1.1 alone would make it a string)
    assert parameter_tree(path) == {"needle.length": 0.2, "needle.elements": 12, "needle.youngs_modulus": 1e9}
    assert parameter_tree({"needle": {"length": 0.3}}) == {"needle": {"length": 0.3}}  # no sections: as it is
    with pytest.raises(FileNotFoundError):
        parameter_tree(tmp_path / "missing.yaml")
