"""Messages on real-recording inputs (QA of own recordings, LOW findings): pose-file errors name the file's line,
misleading messages name the actual mix-up, a sampler window longer than the recording is caught before the
front end, report.md lists only the files written and no false-loop count without ground truth, SIGTERM
cleans up like Ctrl-C, and a number as a config key is one clear line."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest
from helpers.cli import main_in_process, on_scans, run_on_scans
from helpers.streams import write_scans, write_straight_stream

from msa_slam.cli.options import WINDOW_FIX
from msa_slam.datasets import check_scan_folder, open_dataset
from msa_slam.errors import InputError
from msa_slam.io.poses import read_poses, write_poses
from msa_slam.pipeline.config import apply_params, make_config
from msa_slam.pipeline.frontend import check_window
from msa_slam.types import validate_poses

IDENTITY = "1 0 0 0 0 1 0 0 0 0 1 0"


# L1: a pose file's value errors name its line (1-based, comments counted), as its parse errors do


def test_nan_pose_names_the_file_line_counting_comments(tmp_path):
    path = tmp_path / "gt_nan.txt"
    path.write_text("# x-forward LiDAR poses\n" + f"{IDENTITY}\n" * 3 + "1 0 0 nan 0 1 0 0 0 0 1 0\n")
    with pytest.raises(InputError) as err:
        read_poses(path)
    assert str(err.value) == f"{path}:5: pose has NaN or infinite values"


def test_non_rigid_pose_names_the_file_line(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text(f"{IDENTITY}\n\n2 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(InputError, match=r"^.*gt\.txt:3: pose is not a rigid transform \(\|R R\^T - I\| = 3"):
        read_poses(path)


def test_nan_translation_in_a_tum_file_names_its_line(tmp_path):
    path = tmp_path / "gt.tum"
    path.write_text("# t x y z qx qy qz qw\n0.0 0 0 0 0 0 0 1\n0.1 nan 0 0 0 0 0 1\n")
    with pytest.raises(InputError) as err:
        read_poses(path)
    assert str(err.value) == f"{path}:3: pose has NaN or infinite values"


def test_pose_arrays_keep_their_frame_numbers():
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[1, 0, 3] = np.inf
    with pytest.raises(InputError, match="^odometry: frame 1 has NaN or infinite values$"):
        validate_poses(poses, "odometry")


# L2: messages that name the actual mix-up


def test_a_directory_as_pose_file_says_so(tmp_path):
    with pytest.raises(InputError) as err:
        read_poses(tmp_path)
    assert str(err.value) == f"{tmp_path}: is a directory; expected a pose file (KITTI or TUM)"


def test_a_single_scan_as_dataset_names_its_folder(tmp_path):
    scans = write_scans(tmp_path / "scans", 3)
    with pytest.raises(InputError) as err:
        open_dataset(scans / "000001.bin")
    assert str(err.value) == (
        f"{scans / '000001.bin'}: is a single scan file, not a folder of scans; pass the "
        f"folder that holds the scans ({scans})"
    )


def test_kitti_root_without_sequence_lists_its_sequences(tmp_path):
    for name in ("00", "05"):
        write_scans(tmp_path / "kitti" / "sequences" / name / "velodyne", 3)
    with pytest.raises(InputError) as err:
        open_dataset(tmp_path / "kitti")
    assert str(err.value) == (
        f"{tmp_path / 'kitti'}: no scan files (.bin, .ply, .pcd) found; it looks like a KITTI "
        "dataset root: pass --sequence 00 (sequences there: 00, 05)"
    )
    assert len(open_dataset(tmp_path / "kitti", sequence="05")) == 3


def test_sample_clouds_of_a_kitti_sequence_points_to_velodyne(tmp_path):
    from typer.testing import CliRunner

    from msa_slam.cli import app

    write_scans(tmp_path / "seq" / "velodyne", 3)
    (tmp_path / "poses.txt").write_text(f"{IDENTITY}\n" * 3)
    result = CliRunner().invoke(
        app,
        [
            "sample",
            "--poses",
            str(tmp_path / "poses.txt"),
            "--clouds",
            str(tmp_path / "seq"),
            "--sampler",
            "entropy",
            "--out",
            str(tmp_path / "o"),
        ],
    )
    assert isinstance(result.exception, InputError), result.output
    assert str(result.exception) == (
        f"{tmp_path / 'seq'}: no scan files (.bin, .ply, .pcd) found; it looks like a "
        f"KITTI sequence: its scans are in {tmp_path / 'seq' / 'velodyne'}"
    )


def test_a_folder_with_scans_passes_the_folder_check(tmp_path):
    scans = write_scans(tmp_path / "scans", 3)
    (scans / "velodyne").mkdir()  # scans at the top: read as they are, no hint
    check_scan_folder(scans)


# L3: an MSA window longer than the recording, before the front end


def test_window_longer_than_the_frames_without_flush_is_refused():
    config = make_config(dataset="scans", flush=False)
    with pytest.raises(InputError) as err:
        check_window(config, 5, WINDOW_FIX)
    assert str(err.value) == (
        "sampler 'msa': window=10 is longer than the 5 frames read, so it never fills and only "
        "frame 0 becomes a keyframe (flush is off); the evaluation needs at least 3: use a "
        "window of at most 5 frames (-p window=5), -p flush=true or --sampler all"
    )


def test_window_longer_than_the_frames_with_flush_warns_only():
    with pytest.warns(UserWarning, match="window=10 is longer than the stream"):
        check_window(make_config(dataset="scans"), 5, WINDOW_FIX)
    check_window(make_config(dataset="scans", flush=False), 10, WINDOW_FIX)  # fills: nothing to say
    check_window(make_config(dataset="scans", sampler="all", flush=False), 5, WINDOW_FIX)  # no window


def test_run_refuses_a_window_longer_than_the_recording_before_odometry(tmp_path, monkeypatch, capsys):
    scans = write_scans(tmp_path / "scans", 4)
    result = main_in_process(monkeypatch, capsys, *on_scans("run", scans, tmp_path, "-p", "flush=false"))
    assert result.returncode == 2, result.stderr
    assert result.stderr.splitlines()[-1] == (
        "error: sampler 'msa': window=10 is longer than the 4 frames read, so it never fills and only frame 0 becomes "
        "a keyframe (flush is off); the evaluation needs at least 3: use a window of at most 4 frames "
        "(-p window=4), -p flush=true or --sampler all"
    )
    assert "odometry" not in result.stderr and not (tmp_path / "out").exists()


def test_compare_refuses_it_naming_what_compare_can_change(tmp_path, monkeypatch, capsys):
    scans = write_scans(tmp_path / "scans", 4)
    result = main_in_process(monkeypatch, capsys, *on_scans("compare", scans, tmp_path, "-p", "flush=false"))
    assert result.returncode == 2, result.stderr
    assert result.stderr.splitlines()[-1].endswith(
        "the evaluation needs at least 3: use a window of at most 4 frames (-p window=4) or -p flush=true"
    )
    assert "odometry" not in result.stderr


def test_short_stream_warning_is_one_line_before_the_front_end(tmp_path):
    scans, odometry = write_straight_stream(tmp_path, 4)
    result = run_on_scans("run", scans, tmp_path, "--odometry", str(odometry))
    lines = result.stderr.splitlines()
    warned = [i for i, line in enumerate(lines) if "window=10 is longer than the stream" in line]
    assert len(warned) == 1, result.stderr
    assert lines[warned[0]].startswith("warning: msa: window=10")
    assert "UserWarning" not in result.stderr and ".py:" not in result.stderr
    assert warned[0] < next(i for i, line in enumerate(lines) if line.startswith(("odometry", "descriptors")))
    assert "flush at the end" not in result.stderr  # run flushes by default


def test_compare_warns_of_a_short_stream_without_advising_the_flush_it_does(tmp_path):
    scans, odometry = write_straight_stream(tmp_path, 6)
    result = run_on_scans(
        "compare", scans, tmp_path, "--odometry", str(odometry), "--no-sweep", "--no-figures", "--quiet"
    )
    warned = [line for line in result.stderr.splitlines() if "window=10 is longer than the stream" in line]
    assert warned == [
        "warning: msa: window=10 is longer than the stream (6 frames): the window never filled, so only "
        "frame 0 was selected online; only the end-of-stream flush chooses keyframes after it; use a "
        "smaller window"
    ], result.stderr
    assert "flush at the end" not in result.stderr
    assert (tmp_path / "out" / "runs" / "msa" / "metrics.json").is_file()  # msa ran (and flushed) despite it


# L5, L10: report.md


@pytest.fixture(scope="module")
def short_batch(sequence, odometry_file, cache_dir):
    """40 frames with ground truth: no keyframe has one 50 frames back to query, so no PR curve (no pr.csv)."""
    from msa_slam.pipeline import run

    config = make_config(
        dataset=str(sequence),
        source={"frames": 40},
        odometry=str(odometry_file),
        sampler="constant",
        sampler_params={"distance": 1.0},
        cache_dir=str(cache_dir),
    )
    return run(config)


def test_report_lists_only_the_files_written(short_batch, tmp_path):
    from msa_slam.reporting.results import write_run_files

    assert short_batch.pr is None
    write_run_files(short_batch, tmp_path, figures=False)
    report = (tmp_path / "report.md").read_text()
    files = next(line for line in report.splitlines() if line.startswith("Files: "))
    assert not (tmp_path / "pr.csv").exists() and "pr.csv" not in files
    assert not (tmp_path / "steps.csv").exists() and "steps.csv" not in files
    for name in (
        "config.yaml",
        "metrics.json",
        "frames.csv",
        "loops.csv",
        "descriptors.npy",
        "map.ply",
        "pose_graph.g2o",
        "provenance.json",
    ):
        assert (tmp_path / name).exists() and name in files
    assert "0 false (measured pose off ground truth by > 3 m or > 5 deg)." in report


def test_report_without_ground_truth_gives_no_false_loop_count(sequence, odometry_file, cache_dir, tmp_path):
    from msa_slam.pipeline import run
    from msa_slam.reporting.results import write_run_files

    scans = tmp_path / "scans"
    scans.mkdir()
    for scan in sorted((sequence / "velodyne").glob("*.bin"))[:40]:
        shutil.copy(scan, scans / scan.name)
    config = make_config(
        dataset=str(scans),
        mode="realistic",
        odometry=str(odometry_file),
        sampler="constant",
        sampler_params={"distance": 1.0},
        cache_dir=str(cache_dir),
    )
    result = run(config)
    out = tmp_path / "out"
    out.mkdir()
    write_run_files(result, out, figures=False)
    report = (out / "report.md").read_text()
    assert "false loops n/a (no ground truth to check a loop's measured pose against)." in report
    assert "false (measured pose" not in report


# L7: SIGTERM cleans up as Ctrl-C does


def test_sigterm_removes_the_lock_and_the_partial_folder(tmp_path):
    """The process sends itself SIGTERM as it first renames a file into its staging folder (deterministic, no
    timing): it must exit 143 without a traceback, leaving neither `.out.lock` nor `.out.partial-*`."""
    poses = np.tile(np.eye(4), (40, 1, 1))
    poses[:, 0, 3] = np.arange(40) * 1.2
    write_poses(tmp_path / "poses.txt", poses)
    np.save(tmp_path / "desc.npy", np.random.default_rng(1).random((40, 16)))
    code = (
        "import os, signal, sys\n"
        "real = os.replace\n"
        "def replace(src, dst, *a, **k):\n"
        "    if '.partial-' in os.fsdecode(dst):\n"
        "        os.kill(os.getpid(), signal.SIGTERM)\n"
        "    return real(src, dst, *a, **k)\n"
        "os.replace = replace\n"
        "from msa_slam.cli import main\n"
        "sys.argv = ['msa-slam', *sys.argv[1:]]\n"
        "main()\n"
    )
    result = subprocess.run(
        [
            sys.executable,
            "-c",
            code,
            "sample",
            "--poses",
            str(tmp_path / "poses.txt"),
            "--descriptors",
            str(tmp_path / "desc.npy"),
            "-p",
            "window=6",
            "--out",
            str(tmp_path / "out"),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 128 + signal.SIGTERM, result.stderr
    assert "Traceback" not in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["desc.npy", "poses.txt"]


# A number as a key inside a config section


def test_a_number_as_a_section_key_in_a_param_is_one_line():
    with pytest.raises(InputError, match=r"^config: graph: key 1 is not a name; valid keys: "):
        apply_params(make_config(dataset="scans"), ["graph={1: 2}"])
