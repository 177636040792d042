"""needle_batch identify recovers known tissue parameters (bevel K_T, Karnopp C_n) within 5 % from two short
synthetic insertions generated with them (needle_sim_ros.experiments: the truth integrates the protocol's exact base
motion, the pipeline the bag's 200 Hz poses and the FBG shapes carry sensor noise), starting 25 % off, on 2 local
workers; the written params file is one the simulator accepts and holds the estimate."""
import json
import subprocess

import pytest

pytest.importorskip("pandas", reason="needle_batch needs pandas (pip install pandas pyarrow 'dask[distributed]')")
pytest.importorskip("distributed", reason="needle_batch needs dask[distributed]")

from batch_fixtures import TRUE_TISSUE, write_identification_bags  # noqa: E402
from needle_sim_ros.parameters.experiment import node_parameters, node_values  # noqa: E402


def test_identify_recovers_known_tissue_parameters(tmp_path):
    pairs = write_identification_bags(tmp_path / "bags")
    manifest = tmp_path / "bags.txt"
    manifest.write_text("".join(f"{bag} {experiment}\n" for bag, experiment in pairs))
    out = tmp_path / "fit"
    result = subprocess.run(["needle_batch", "identify", "--bags", str(manifest), "--workers", "2", "--quiet",
                             "--fit", "tissue.layers.tip_stiffness[0]=9.0e3",
                             "--fit", "needle_simulator:tissue.layers.friction_coulomb[0]=6.0",
                             "--output-dir", str(out)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads((out / "identification.json").read_text())
    truth = [TRUE_TISSUE["tissue.layers.tip_stiffness"][0], TRUE_TISSUE["tissue.layers.friction_coulomb"][0]]
    for estimate, std, true in zip(report["estimate"], report["std"], truth):
        assert abs(estimate - true) <= 0.05 * true, (estimate, true)
        assert 0 < std < 0.2 * true
    assert [b["bag"] for b in report["per_bag"]] == [str(bag) for bag, _ in pairs]
    assert all(b["rms_final"] < b["rms_initial"] for b in report["per_bag"])
    history = (out / "fit_history.csv").read_text().splitlines()
    assert len(history) - 1 == report["evaluations"] >= 3
    values = node_parameters("needle_simulator", node_values([out / "identified_params.yaml"], "needle_simulator"))
    assert values["tissue.layers.tip_stiffness"] == [pytest.approx(report["estimate"][0])]
    assert values["tissue.layers.friction_coulomb"] == [pytest.approx(report["estimate"][1])]
