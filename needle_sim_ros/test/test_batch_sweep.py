"""needle_batch sweep on a LocalCluster of 2 processes over the sample bags: the same numbers as needle_offline run
bag by bag, failed rows for a corrupt and a missing bag, --resume reruns only what did not finish, and the tables of
1 worker, of 2 and of an existing scheduler are equal. Installed executables, run from the repository root (the
sample experiment files name the stereo calibration files relative to it, as for needle_offline); outputs in a
temporary folder."""
import json
import shutil
import subprocess
import time
from pathlib import Path

import pytest

pd = pytest.importorskip("pandas", reason="needle_batch needs pandas (pip install pandas pyarrow 'dask[distributed]')")
pytest.importorskip("distributed", reason="needle_batch needs dask[distributed]")

REPO = Path(__file__).resolve().parents[2]
BAGS = ("dynamic_pitch", "insertion", "static_tip_load")
DURATION = "1.6"  # s: the first stereo pair with the needle is at 1.5 s
BETAS = (1.0e-4, 3.0e-4)
GRID = "sweep:\n  needle_simulator:\n    ros__parameters:\n      damping.rayleigh_beta: [1.0e-4, 3.0e-4]\n"
COLUMN = "needle_simulator:damping.rayleigh_beta"


def run(*args):
    return subprocess.run(list(args), cwd=REPO, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    work = tmp_path_factory.mktemp("sweep")
    corrupt = work / "corrupt.mcap"
    corrupt.write_bytes((REPO / "bags/insertion.mcap").read_bytes()[:20000])  # cut off mid-chunk
    lines = [f"{REPO}/bags/{b}.mcap {REPO}/config/experiments/{b}.yaml" for b in BAGS]
    lines += [f"{corrupt} {REPO}/config/experiments/insertion.yaml", f"{work}/missing.mcap"]
    (work / "bags.txt").write_text("\n".join(lines) + "\n")
    (work / "grid.yaml").write_text(GRID)
    out = work / "out"
    result = run("needle_batch", "sweep", "--bags", str(work / "bags.txt"), "--grid", str(work / "grid.yaml"),
                 "--duration", DURATION, "--workers", "2", "--output-dir", str(out), "--quiet")
    return work, out, result


def test_sweep_writes_a_row_per_bag_and_set_and_failed_rows_for_bad_bags(sweep):
    work, out, result = sweep
    assert result.returncode == 1, result.stderr  # some rows failed; the batch still completed
    assert "Traceback" not in result.stderr
    table = pd.read_parquet(out / "results.parquet")
    csv = pd.read_csv(out / "results.csv")
    assert len(table) == len(csv) == 5 * len(BETAS)
    ok = table[table["status"] == "ok"]
    assert sorted(Path(b).stem for b in ok["bag"].unique()) == sorted(BAGS)
    assert len(ok) == len(BAGS) * len(BETAS) and (ok["compared"] > 0).all()
    failed = table[table["status"] == "failed"].set_index(table[table["status"] == "failed"]["bag"].map(
        lambda b: Path(b).stem))
    assert "missing.mcap' does not exist" in failed.loc["missing", "error"].iloc[0]
    assert failed.loc["corrupt", "error"].iloc[0]
    assert failed["rmse_mean_m"].isna().all()
    assert ok["wrench_force_rms_n"].notna().all()  # every sample bag has a reference wrench
    assert (out / "plots" / f"{COLUMN.replace(':', '_')}.png").is_file()


@pytest.mark.parametrize("bag", BAGS)
def test_rows_match_needle_offline_bag_by_bag(sweep, bag):
    work, out, _ = sweep
    table = pd.read_parquet(out / "results.parquet")
    for beta in BETAS:
        target = work / f"offline_{bag}_{beta}"
        result = run("needle_offline", f"{REPO}/bags/{bag}.mcap", "--experiment",
                     f"{REPO}/config/experiments/{bag}.yaml", "--duration", DURATION, "--set",
                     f"needle_simulator:damping.rayleigh_beta={beta}", "--no-plots",
                     "--quiet", "--output-dir", str(target))
        assert result.returncode == 0, result.stderr
        expected = json.loads((target / "summary.json").read_text())["comparison"]
        row = table[(table["bag"] == f"{REPO}/bags/{bag}.mcap") & (table[COLUMN] == beta)].iloc[0]
        assert row["compared"] == expected["compared"]
        for key in ("rmse_mean_m", "rmse_max_m", "tip_error_mean_m"):
            assert row[key] == expected[key], key  # exactly


def test_resume_reruns_only_unfinished_tasks_and_one_worker_gives_the_same_table(sweep):
    work, out, _ = sweep
    before = pd.read_parquet(out / "results.parquet")
    result = run("needle_batch", "sweep", "--bags", str(work / "bags.txt"), "--grid", str(work / "grid.yaml"),
                 "--duration", DURATION, "--workers", "1", "--output-dir", str(out), "--quiet", "--resume",
                 "--no-plots")
    assert "ran 4, reused 6" in result.stdout, result.stdout + result.stderr
    after = pd.read_parquet(out / "results.parquet")
    pd.testing.assert_frame_equal(before[before["status"] == "ok"], after[after["status"] == "ok"])
    # one worker from scratch, insertion only: the same rows as with two workers (wall time aside)
    shutil.copy(REPO / "bags/insertion.mcap", work / "insertion.mcap")
    result = run("needle_batch", "sweep", "--bags", str(work / "insertion.mcap"), "--experiment",
                 f"{REPO}/config/experiments/insertion.yaml", "--grid", str(work / "grid.yaml"), "--duration", DURATION,
                 "--workers", "1", "--output-dir", str(work / "one"), "--quiet", "--no-plots")
    assert result.returncode == 0, result.stderr
    one = pd.read_parquet(work / "one" / "results.parquet").drop(columns=["bag", "wall_s", "key"])
    two = before[before["bag"] == f"{REPO}/bags/insertion.mcap"].drop(columns=["bag", "wall_s", "key"])
    pd.testing.assert_frame_equal(one.reset_index(drop=True), two.reset_index(drop=True))


def test_an_existing_scheduler_gives_the_same_table(sweep, tmp_path):
    """--scheduler: a scheduler and a worker started apart from needle_batch (as on a cluster, `dask scheduler` /
    `dask worker`); the insertion rows equal those of the LocalCluster run (wall time aside)."""
    work, out, _ = sweep
    address_file = tmp_path / "scheduler.json"
    scheduler = subprocess.Popen(["dask", "scheduler", "--port", "0", "--dashboard-address", ":0",
                                  "--scheduler-file", str(address_file)], cwd=REPO, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL)
    worker = subprocess.Popen(["dask", "worker", "--scheduler-file", str(address_file), "--nthreads", "1",
                               "--nworkers", "1", "--dashboard-address", ":0"], cwd=REPO, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    try:
        for _ in range(300):
            if address_file.exists() and address_file.stat().st_size:
                break
            time.sleep(0.1)
        address = json.loads(address_file.read_text())["address"]
        result = run("needle_batch", "sweep", "--bags", str(REPO / "bags/insertion.mcap"), "--experiment",
                     f"{REPO}/config/experiments/insertion.yaml", "--grid", str(work / "grid.yaml"), "--duration",
                     DURATION, "--scheduler", address, "--output-dir", str(tmp_path / "remote"), "--quiet",
                     "--no-plots")
    finally:
        for process in (worker, scheduler):
            process.terminate()
            process.wait(timeout=30)
    assert result.returncode == 0, result.stdout + result.stderr
    remote = pd.read_parquet(tmp_path / "remote" / "results.parquet").drop(columns=["bag", "wall_s", "key"])
    local = pd.read_parquet(out / "results.parquet")
    local = local[local["bag"] == f"{REPO}/bags/insertion.mcap"].drop(columns=["bag", "wall_s", "key"])
    pd.testing.assert_frame_equal(remote.reset_index(drop=True), local.reset_index(drop=True))
