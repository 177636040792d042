"""Grid files and bag lists of needle_batch (no cluster): counts and order against hand-enumerated sets."""
from pathlib import Path

import pytest

pytest.importorskip("pandas", reason="needle_batch needs pandas (pip install pandas pyarrow 'dask[distributed]')")

from needle_sim_ros.batch.bags import BagListError, content_hash, resolve_bags  # noqa: E402
from needle_sim_ros.batch.grid import GridError, load_grid  # noqa: E402
from needle_sim_ros.batch.task import TaskSpec  # noqa: E402


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "grid.yaml"
    path.write_text(text)
    return path


def test_sweep_is_the_full_factorial_in_file_order_plus_points(tmp_path):
    grid = load_grid(write(tmp_path, """
sweep:
  needle_simulator:
    ros__parameters:
      damping:
        rayleigh_beta: [1.0e-4, 2.0e-4]
      tissue.layers.tip_stiffness: [[9.0e+3], [1.0e+4], [1.1e+4]]
points:
  - needle_compare: {ros__parameters: {tolerance: 0.02}}
"""))
    assert len(grid.parameter_sets) == 2 * 3 + 1
    assert grid.parameter_sets[0] == {"needle_simulator": {"damping.rayleigh_beta": 1e-4,
                                                           "tissue.layers.tip_stiffness": [9e3]}}
    assert grid.parameter_sets[1]["needle_simulator"]["tissue.layers.tip_stiffness"] == [1e4]  # last varies fastest
    assert grid.parameter_sets[3]["needle_simulator"]["damping.rayleigh_beta"] == 2e-4
    assert grid.parameter_sets[-1] == {"needle_compare": {"tolerance": 0.02}}
    assert grid.columns == ["needle_simulator:damping.rayleigh_beta", "needle_simulator:tissue.layers.tip_stiffness",
                            "needle_compare:tolerance"]


@pytest.mark.parametrize("text, message", [
    ("sweep: {needle_simulator: {ros__parameters: {damping.rayleigh_gamma: [1.0]}}}", "no parameter"),
    ("sweep: {needle_simulator: {ros__parameters: {tissue.layers.tip_stiffness: [9.0e+3, 1.0e+4]}}}",
     "list of arrays"),
    ("sweep: {needle_simulator: {ros__parameters: {damping.rayleigh_beta: [-1.0]}}}", "rayleigh_beta"),
    ("sweep: {needle_simulator: {ros__parameters: {damping.rayleigh_beta: 1.0}}}", "non-empty list"),
    ("sweep: {needle_nothing: {ros__parameters: {a: [1]}}}", "unknown node"),
    ("grid: {}", "top-level"),
    ("sweep: [", "not YAML"),
])
def test_bad_grid_files_are_named_with_the_problem(tmp_path, text, message):
    with pytest.raises(GridError, match=message) as error:
        load_grid(write(tmp_path, text))
    assert "grid.yaml" in str(error.value) and "\n" not in str(error.value)


def test_bag_lists_and_content_keys(tmp_path):
    for name in ("b.mcap", "a.mcap", "notes.txt"):
        (tmp_path / name).write_bytes(name.encode())
    assert [Path(e.path).name for e in resolve_bags(str(tmp_path))] == ["a.mcap", "b.mcap"]
    assert [Path(e.path).name for e in resolve_bags(str(tmp_path / "*.mcap"))] == ["a.mcap", "b.mcap"]
    manifest = tmp_path / "list.txt"
    manifest.write_text("# bags\nb.mcap exp.yaml\n/abs/missing.mcap\n")
    entries = resolve_bags(str(manifest))
    assert (entries[0].path, entries[0].experiment) == (str(tmp_path / "b.mcap"), str(tmp_path / "exp.yaml"))
    assert entries[1].path == "/abs/missing.mcap"
    with pytest.raises(BagListError, match="no such"):
        resolve_bags(str(tmp_path / "nothing"))
    # same content, same key; other content or parameters, another key
    same = TaskSpec("x", content_hash(str(tmp_path / "a.mcap")), "e", {"n": {"p": 1}})
    assert same.key == TaskSpec("y", content_hash(str(tmp_path / "a.mcap")), "e", {"n": {"p": 1}}).key
    assert same.key != TaskSpec("x", content_hash(str(tmp_path / "b.mcap")), "e", {"n": {"p": 1}}).key
    assert same.key != TaskSpec("x", same.bag_hash, "e", {"n": {"p": 2}}).key
    assert content_hash(str(tmp_path / "missing.mcap")) == "missing"


def test_the_installed_example_grid_loads():
    from ament_index_python.packages import get_package_share_directory
    grid = load_grid(Path(get_package_share_directory("needle_sim_ros")) / "config/batch/sweep_example.yaml")
    assert len(grid.parameter_sets) == 2 * 2 + 2
    assert grid.parameter_sets[1]["needle_simulator"]["tissue.layers.tip_stiffness"] == [1.2e4]
    assert grid.parameter_sets[-1]["needle_simulator"]["tissue.layers.friction_coulomb"] == [8.0]


def test_unusable_inputs_end_the_batch_before_a_cluster_starts(tmp_path, capsys):
    """A missing single bag, a bag without an experiment file, an output folder that cannot be one: exit 2 and one
    line, before a cluster starts (before: a cluster, every task a failed row, exit 1; the output folder: after
    all the tasks ran)."""
    from needle_sim_ros.batch.cli import main
    grid = write(tmp_path, "sweep:\n  needle_simulator:\n    ros__parameters:\n      needle.elements: [4, 6]\n")
    bag = tmp_path / "lab_run.mcap"
    bag.write_bytes(b"not read before the tasks")
    experiment = tmp_path / "lab.yaml"
    experiment.write_text("needle_simulator:\n  ros__parameters: {}\n")
    blocker = tmp_path / "results"
    blocker.write_text("a file")
    cases = [(["--bags", str(tmp_path / "absent.mcap")], "--bags '"),
             (["--bags", str(bag)], f"bag '{bag}': no experiment file"),
             (["--bags", str(bag), "--experiment", str(experiment), "--output-dir", str(blocker)],
              f"--output-dir '{blocker}' is a file"),
             (["--bags", str(bag), "--experiment", str(experiment), "--output-dir", str(blocker / "sub")],
              "a file is in the way")]
    for arguments, words in cases:
        assert main(["sweep", "--grid", str(grid), "--workers", "1", "--quiet", *arguments]) == 2, arguments
        err = capsys.readouterr().err
        assert err.startswith("needle_batch: error: ") and words in err and err.count("\n") == 1, err
    assert blocker.read_text() == "a file"
