"""`line_odom batch` over a small archive made from ../shared/data (KITTI as bags and as folders, a TUM folder, a
truncated bag): local workers and a local Dask cluster give the same trajectories; the summary's rows, aggregates
and the failed row's error; a second run skips what is complete; manifests; a worker that dies is retried once;
Ctrl-C leaves no half-written outputs."""
import csv
import fcntl
import io
import json
import os
import re
import signal
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pytest

from line_odom import batch
from line_odom.cli import main

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import batch as bench_batch  # noqa: E402
import distributed  # noqa: E402  (line_odom batch's engine: requirements/dev.txt, installed by make setup)

KITTI_FRAMES, TUM_FRAMES = 4, 5
OK_LABELS = ["kitti__00", "kitti__04", "kitti__04_bag", "kitti__07_mcap", "tum__rgbd_dataset_freiburg1_xyz"]
BROKEN = "broken__truncated_bag"
OUTPUT_FILES = ("trajectory_tum.txt", "trajectory_kitti.txt", "ground_truth_tum.txt", "metrics.json", "trajectory.png",
                batch.RECORD)


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    root = tmp_path_factory.mktemp("archive")
    return root, bench_batch.make_archive(root, KITTI_FRAMES, TUM_FRAMES)


@pytest.fixture(scope="module")
def cluster():
    """A local Dask cluster started by the test, one worker (the local run has two), the scheduler set as
    line_odom.batch sets its own so that a worker death reaches the client at once."""
    with batch.local_cluster(1) as c:
        yield c


def _rows(out: Path) -> dict[str, dict]:
    with open(out / batch.SUMMARY_CSV, newline="") as f:
        return {r["label"]: r for r in csv.DictReader(f)}


def _trajectories(out: Path, labels) -> dict[str, bytes]:
    return {label: [(out / label / name).read_bytes() for name in ("trajectory_tum.txt", "trajectory_kitti.txt")]
            for label in labels}


def _is_commit(sha: str) -> bool:
    """A commit of this checkout (HEAD can move while the test runs when others commit)."""
    done = subprocess.run(["git", "-C", str(ROOT), "cat-file", "-t", sha], capture_output=True, text=True)
    return len(sha) == 40 and done.stdout.strip() == "commit"


def test_local_workers_and_a_cluster_give_the_same_trajectories_and_the_summary(archive, cluster, tmp_path, capsys):
    root, paths = archive
    out = tmp_path / "local"
    assert main(["batch", str(root), "--out", str(out), "--workers", "2", "--set", "downsample=6", "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"line_odom batch: error: 1 of 6 recordings failed ({BROKEN}; errors in {out / batch.SUMMARY_MD})"]

    rows = _rows(out)
    assert list(rows) == [BROKEN] + OK_LABELS + ["mean", "median", "worst"]  # the notes/ folder is no recording
    assert [rows[k]["kind"] for k in OK_LABELS] == ["kitti", "kitti", "rosbag2", "rosbag2", "tum"]
    for label in OK_LABELS:
        r = rows[label]
        metrics = json.loads((out / label / "metrics.json").read_text())
        assert r["status"] == "ok" and r["error"] == "" and float(r["seconds"]) > 0 and r["attempts"] == "1"
        assert r["host"] == socket.gethostname() and _is_commit(r["commit"].split()[0])
        assert int(r["frames"]) == (TUM_FRAMES if label.startswith("tum") else KITTI_FRAMES)
        assert float(r["rpe_trans_mean_m"]) == pytest.approx(metrics["rpe_trans_mean_m"], rel=1e-5)
        for name in OUTPUT_FILES:
            assert (out / label / name).stat().st_size > 0, (label, name)
    failed = rows[BROKEN]
    assert failed["status"] == "failed" and failed["rpe_trans_mean_m"] == "" and not (out / BROKEN).exists()
    assert failed["error"].startswith(f"{paths[BROKEN]}: ") and "truncated" in failed["error"]
    # the one line `line_odom replay` prints for it
    assert main(["replay", str(paths[BROKEN]), "--out", str(tmp_path / "replayed"), "--quiet"]) == 1
    assert capsys.readouterr().err.strip() == f"line_odom replay: error: {failed['error']}"
    values = [json.loads((out / k / "metrics.json").read_text())["rpe_trans_mean_m"] for k in OK_LABELS]
    assert rows["mean"]["status"] == "aggregate"
    assert float(rows["mean"]["rpe_trans_mean_m"]) == pytest.approx(statistics.fmean(values), rel=1e-5)
    assert float(rows["median"]["rpe_trans_mean_m"]) == pytest.approx(statistics.median(values), rel=1e-5)
    assert float(rows["worst"]["rpe_trans_mean_m"]) == pytest.approx(max(values), rel=1e-5)
    assert rows["worst"]["frames"] == str(KITTI_FRAMES)  # fewest frames is the worst
    md = (out / batch.SUMMARY_MD).read_text()
    assert "failed: 1" in md and f"- {BROKEN} (`{paths[BROKEN]}`): {failed['error']}" in md
    commit = rows[OK_LABELS[0]]["commit"].split()[0]
    assert f"commit {commit}" in md and socket.gethostname() in md
    assert (out / batch.SUMMARY_PLOT).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (out / batch.TMP_DIR).exists()

    # the second run (on the test's cluster: no local one to start) skips what is complete and tries the failed
    # recording again
    stamps = {k: (out / k / "trajectory_tum.txt").stat().st_mtime_ns for k in OK_LABELS}
    assert main(["batch", str(root), "--out", str(out), "--cluster", cluster.scheduler_address, "--set", "downsample=6",
                 "--quiet"]) == 1
    again = _rows(out)
    assert [(again[k]["status"], again[k]["attempts"]) for k in OK_LABELS] == [("skipped", "0")] * len(OK_LABELS)
    assert [again[k]["seconds"] for k in OK_LABELS] == [rows[k]["seconds"] for k in OK_LABELS]
    assert again[BROKEN]["status"] == "failed" and again[BROKEN]["error"] == failed["error"]
    assert {k: (out / k / "trajectory_tum.txt").stat().st_mtime_ns for k in OK_LABELS} == stamps

    # the same recordings from a YAML manifest, on the test's cluster of one worker; and KITTI 04 once more, judged
    # against a ground-truth file (the one the first run wrote for it), the format named
    manifest = tmp_path / "archive.yaml"
    manifest.write_text("recordings:\n" + "".join(
        f"  - {{path: {paths[k]}, label: {k}, set: {{downsample: 6}}}}\n" for k in OK_LABELS)
        + f"  - {{path: {paths['kitti__04']}, label: gt_file, format: kitti, set: {{downsample: 6}}, "
          f"ground_truth: {out / 'kitti__04' / 'ground_truth_tum.txt'}}}\n")
    on_cluster = tmp_path / "cluster"
    assert main(["batch", str(manifest), "--out", str(on_cluster), "--cluster", cluster.scheduler_address,
                 "--quiet"]) == 0
    assert [r["status"] for r in list(_rows(on_cluster).values())[:-3]] == ["ok"] * (len(OK_LABELS) + 1)
    assert _trajectories(on_cluster, OK_LABELS) == _trajectories(out, OK_LABELS)
    by_file = json.loads((on_cluster / "gt_file" / "metrics.json").read_text())
    own = json.loads((out / "kitti__04" / "metrics.json").read_text())
    assert by_file["frames_with_ground_truth"] == own["frames_with_ground_truth"] == KITTI_FRAMES
    assert by_file["rpe_trans_mean_m"] == pytest.approx(own["rpe_trans_mean_m"], rel=1e-6)

    # other parameters are another task: replayed although outputs exist; --force replays complete ones
    csv_manifest = tmp_path / "one.csv"
    csv_manifest.write_text(f"path,label,set\n{paths['kitti__07_mcap']},kitti__07_mcap,downsample=8\n")
    before = (on_cluster / "kitti__07_mcap" / "trajectory_tum.txt").read_bytes()
    assert main(["batch", str(csv_manifest), "--out", str(on_cluster), "--cluster", cluster.scheduler_address,
                 "--quiet"]) == 0
    assert _rows(on_cluster)["kitti__07_mcap"]["status"] == "ok"
    assert (on_cluster / "kitti__07_mcap" / "trajectory_tum.txt").read_bytes() != before
    stamp = (on_cluster / "kitti__07_mcap" / "trajectory_tum.txt").stat().st_mtime_ns
    scheduler_file = tmp_path / "scheduler.json"  # the cluster named as `dask scheduler --scheduler-file` names it
    scheduler_file.write_text(json.dumps({"type": "Scheduler", "address": cluster.scheduler_address}))
    assert main(["batch", str(csv_manifest), "--out", str(on_cluster), "--cluster", str(scheduler_file),
                 "--quiet", "--force"]) == 0
    assert _rows(on_cluster)["kitti__07_mcap"]["status"] == "ok"
    assert (on_cluster / "kitti__07_mcap" / "trajectory_tum.txt").stat().st_mtime_ns != stamp


def test_manifests_yaml_and_csv(tmp_path):
    (tmp_path / "params.yaml").write_text("line_odom:\n  ros__parameters: {}\n")
    (tmp_path / "runs").mkdir()
    yaml_manifest = tmp_path / "m.yaml"
    yaml_manifest.write_text("- path: runs/a\n  label: first\n  params: params.yaml\n  set: {downsample: 8}\n"
                             "- path: runs/b\n  set: ['ransac.seed=3', 'input=pointcloud']\n"
                             "- runs/c\n")
    recs = batch.recordings_from(yaml_manifest, overrides={"downsample": 6, "threads": 1})
    assert [r.label for r in recs] == ["first", "b", "c"]
    assert [r.path for r in recs] == [tmp_path / "runs" / n for n in "abc"]
    assert recs[0].params == str(tmp_path / "params.yaml") and recs[1].params is None
    assert recs[0].overrides == {"downsample": 8, "threads": 1}  # the entry's own set wins
    assert recs[1].overrides == {"downsample": 6, "threads": 1, "ransac.seed": 3, "input": "pointcloud"}
    assert recs[2].kind is None  # not a recording: that task fails, the others run
    # the error is replay's readers' own, naming the path
    row = batch.run_recording(recs[2], tmp_path / "out")
    assert row["status"] == "failed" and row["error"].startswith(f"{tmp_path / 'runs' / 'c'}: no such")
    (tmp_path / "runs" / "c").mkdir()
    row = batch.run_recording(recs[2], tmp_path / "out")
    assert row["status"] == "failed" and row["error"].startswith(f"{tmp_path / 'runs' / 'c'}: unknown recording format")

    csv_manifest = tmp_path / "m.csv"
    csv_manifest.write_text("# archive\npath,label,set,params,format,ground_truth\n"
                            "runs/a,,downsample=8; ransac.seed=2,,,\n"
                            f"{tmp_path / 'runs' / 'b'},bee,,params.yaml,velodyne,gt/b_poses.txt\n")
    recs = batch.read_manifest(csv_manifest)
    assert [(r.label, r.overrides, r.params, r.kind, r.ground_truth) for r in recs] == [
        ("a", {"downsample": 8, "ransac.seed": 2}, None, None, None),
        ("bee", {}, str(tmp_path / "params.yaml"), "velodyne", str(tmp_path / "gt" / "b_poses.txt"))]

    for text, message in [
        ("- label: x\n", "entry 1: 'path' is missing"),
        ("- {path: runs/a, sets: {a: 1}}\n",
         "entry 1: unknown field(s) sets (expected path, label, params, set, format, ground_truth)"),
        ("- {path: runs/a, format: pcap}\n", "entry 1: format 'pcap': expected one of rosbag2, "),
        ("- runs/a\n- {path: runs/b, label: a}\n", "label 'a' is given to both"),
        ("- {path: runs/a, set: 3}\n", "entry 1: 'set' must be a mapping NAME: VALUE or a list"),
        ("- {path: runs/a, set: [downsample]}\n", "entry 1: --set: expected NAME=VALUE, got 'downsample'"),
        ("- {path: runs/a, label: ../up}\n", "label '../up' of"),
        ("runs: [a]\n", "expected a list of entries or a mapping with the one key 'recordings'"),
        ("[]\n", "the manifest lists no recordings"),
    ]:
        yaml_manifest.write_text(text)
        with pytest.raises(ValueError, match="^" + str(yaml_manifest)) as info:
            batch.read_manifest(yaml_manifest)
        assert message in str(info.value), (text, str(info.value))
    csv_manifest.write_text("recording,label\nruns/a,x\n")
    with pytest.raises(ValueError, match="the first row must name the columns, with 'path' among them"):
        batch.read_manifest(csv_manifest)
    (tmp_path / "m.txt").write_text("runs/a\n")
    with pytest.raises(ValueError, match=r"a manifest must be \.yaml, \.yml or \.csv"):
        batch.recordings_from(tmp_path / "m.txt")
    with pytest.raises(ValueError, match="no recording found"):
        batch.recordings_from(tmp_path / "runs")
    assert main(["batch", str(tmp_path / "runs"), "--out", str(tmp_path / "o"), "--workers", "1",
                 "--cluster", "tcp://127.0.0.1:1"]) == 2
    # one batch at a time writes into a folder
    (tmp_path / "one.yaml").write_text("- runs/c\n")
    (tmp_path / "o").mkdir()
    with open(tmp_path / "o" / batch.LOCK, "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        with pytest.raises(RuntimeError, match=f"^{tmp_path / 'o'}: another line_odom batch is writing into this"):
            batch.run_batch(tmp_path / "one.yaml", tmp_path / "o", workers=1)


def _dies_unless_retried(rec, out_root, frames):
    """Task for the test below: its worker process dies on the first attempt ("once") or on every attempt."""
    marker = Path(out_root) / f"attempted.{rec.label}"
    if rec.label == "always" or not marker.exists():
        marker.touch()
        os._exit(3)
    return batch.run_recording(rec, out_root, frames)


def test_a_worker_that_dies_is_retried_once_then_reported(archive, cluster, tmp_path):
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the worker cannot import this test module
    _, paths = archive
    recs = [batch.Recording(paths["kitti__07_mcap"], "once", "rosbag2", overrides={"downsample": 6}),
            batch.Recording(paths["kitti__07_mcap"], "always", "rosbag2", overrides={"downsample": 6})]
    with distributed.Client(cluster) as client:
        once, = batch.execute(client, recs[:1], tmp_path, task=_dies_unless_retried)
        always, = batch.execute(client, recs[1:], tmp_path, task=_dies_unless_retried)
    assert once["status"] == "ok" and once["attempts"] == 2 and (tmp_path / "once" / batch.RECORD).is_file()
    assert always["status"] == "failed" and always["attempts"] == 2 and not (tmp_path / "always").exists()
    assert always["error"].startswith("the worker process running it died twice (KilledWorker: ")


def test_ctrl_c_leaves_complete_outputs_or_none(archive, tmp_path):
    _, paths = archive
    # six recordings on one worker: the run is still going when the signal comes after the first
    labels = [f"kitti__04_{i}" for i in range(6)]
    manifest = tmp_path / "six.csv"
    manifest.write_text("path,label,set\n" + "".join(f"{paths['kitti__04_bag']},{k},downsample=6\n" for k in labels))
    out = tmp_path / "out"
    # a new session, signalled as a terminal's Ctrl-C signals its foreground group: the batch and its workers. Python
    # raises KeyboardInterrupt only where SIGINT was not ignored at its start, as it is under a CI runner's nohup
    # or a shell's background job: the handler is set first.
    run = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
           "from line_odom.cli import main; sys.exit(main(sys.argv[1:]))")
    proc = subprocess.Popen([sys.executable, "-c", run, "batch", str(manifest), "--out", str(out), "--workers", "1",
                             "--quiet"], cwd=ROOT, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any((out / k).is_dir() for k in labels):
            time.sleep(0.02)
        assert any((out / k).is_dir() for k in labels), "no recording finished"
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130 and err.strip() == "line_odom: interrupted", err
    assert not (out / batch.TMP_DIR).exists()
    rows = _rows(out)
    assert 1 <= sum(rows[k]["status"] == "ok" for k in labels) < len(labels)
    for label in labels:
        if (out / label).exists():  # finished before the workers stopped: complete
            assert all((out / label / name).is_file() for name in OUTPUT_FILES) and rows[label]["status"] == "ok"
        else:
            assert rows[label]["status"] == "interrupted" and rows[label]["error"] == "not run (interrupted)"
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [batch.LOCK, batch.SUMMARY_CSV, batch.SUMMARY_MD, batch.SUMMARY_PLOT]
        + [k for k in labels if (out / k).is_dir()])


def test_discovery_finds_each_recording_once(archive, tmp_path):
    root, paths = archive
    (root / "kitti" / "loop").symlink_to(root / "kitti")  # a link back up is not followed twice
    (root / "kitti" / "04_bag" / "stray.txt").write_text("inside a recording: not searched\n")
    try:
        found = batch.discover(root)
    finally:
        (root / "kitti" / "loop").unlink()
        (root / "kitti" / "04_bag" / "stray.txt").unlink()
    assert [(r.label, r.kind, r.path) for r in found] == [(k, kind, paths[k].resolve()) for k, kind in [
        (BROKEN, "rosbag2"), ("kitti__00", "kitti"), ("kitti__04", "kitti"), ("kitti__04_bag", "rosbag2"),
        ("kitti__07_mcap", "rosbag2"), ("tum__rgbd_dataset_freiburg1_xyz", "tum")]]
    # a recording given as INPUTS is the one task, labelled with its name
    assert [(r.label, r.kind) for r in batch.discover(paths["kitti__04"])] == [("04", "kitti")]
    # the output folder inside INPUTS is not searched (its outputs are no recordings, but a manifest's may be)
    assert batch.discover(root, exclude=[root / "kitti"])[1:] == [found[-1]]


def test_progress_counts_done_and_failed_with_an_eta():
    stream = io.StringIO()
    bar = batch.BatchProgress(3, enabled=True, stream=stream)
    bar.min_interval_s = 0.0
    bar.to_run = 2
    bar.count({"status": "skipped"})
    assert re.search(r"\] 1/3 done, 0 failed +[0-9.]+s ETA    -$", stream.getvalue())
    bar.count({"status": "failed"})
    assert "2/3 done, 1 failed" in stream.getvalue().rsplit("\r", 1)[-1]
    assert "ETA    -" not in stream.getvalue().rsplit("\r", 1)[-1]  # one of two run: the other's time estimated
    bar.count({"status": "ok"})
    bar.close()
    assert stream.getvalue().rsplit("\r", 1)[-1].startswith(f"batch [{'#' * bar.width}] 3/3 done, 1 failed")


def test_the_node_does_not_import_the_engine():
    code = "import sys, line_odom.node, line_odom.lifecycle_node, line_odom.cli, line_odom.replay; " \
           "sys.exit(any(m.split('.')[0] in ('dask', 'distributed') for m in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT, timeout=120).returncode == 0


def test_batch_without_dask_says_what_to_install_in_one_line(archive, tmp_path):
    """Dask is an optional extra: where it is not installed, `batch` says what to install; nothing else needs it."""
    root, _ = archive
    hide = ("import sys; sys.modules['dask'] = sys.modules['distributed'] = None; "  # as if not installed
            "from line_odom.cli import main; sys.exit(main(sys.argv[1:]))")
    done = subprocess.run([sys.executable, "-c", hide, "batch", str(root), "--out", str(tmp_path / "out"), "--quiet"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 1 and done.stderr.strip() == f"line_odom batch: error: {batch.DEPENDENCY_HINT}", \
        done.stderr
    assert "pip install dask distributed" in batch.DEPENDENCY_HINT


def test_benchmark_prints_one_and_two_workers_and_the_speed_up(capsys):
    """bench/batch.py: the wall time of the same archive on 1 and 2 local workers, the speed-up, and that the two runs
    gave the same trajectories."""
    assert bench_batch.main(["--kitti-frames", "2", "--tum-frames", "2"]) == 0
    out = capsys.readouterr().out
    walls = {int(w): float(s) for w, s in re.findall(r"^workers (\d): wall +([0-9.]+) s +\(5 replayed, 1 failed",
                                                        out, flags=re.MULTILINE)}
    assert sorted(walls) == [1, 2] and all(s > 0 for s in walls.values()), out
    speed_up = float(re.search(r"^speed-up 2 vs 1 workers: ([0-9.]+)x$", out, flags=re.MULTILINE).group(1))
    assert speed_up == pytest.approx(walls[1] / walls[2], abs=0.01)
    assert "trajectories identical between 1 and 2 workers: True" in out
