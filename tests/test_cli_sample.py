"""`msa-slam sample` end to end on files, and its error messages."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.errors import InputError
from msa_slam.io.poses import write_poses
from msa_slam.sampling import make_sampler
from msa_slam.sampling.registry import sampler_parameters

runner = CliRunner()


@pytest.fixture
def stream(tmp_path):
    rng = np.random.default_rng(0)
    n = 60
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :2, 3] = np.cumsum(rng.uniform(0.3, 1.0, (n, 2)), axis=0)
    desc = np.cumsum(rng.standard_normal((n, 16)), axis=0)
    clouds = rng.uniform(-20, 20, (n, 50, 3))
    write_poses(tmp_path / "poses.txt", poses, "kitti")
    write_poses(tmp_path / "poses_tum.txt", poses, "tum")
    np.save(tmp_path / "desc.npy", desc)
    np.save(tmp_path / "clouds.npy", clouds)
    return tmp_path, poses, desc


def invoke(*args):
    return runner.invoke(app, ["sample", *map(str, args), "--quiet"])


def test_sample_writes_text_json_and_png(stream):
    path, poses, desc = stream
    result = invoke(
        "--poses", path / "poses.txt", "--descriptors", path / "desc.npy", "-p", "window=8", "--out", path / "out"
    )
    assert result.exit_code == 0, result.output
    expected = make_sampler("msa", window=8).run(poses, desc)
    text = [int(v) for v in (path / "out" / "keyframes.txt").read_text().split()]
    record = json.loads((path / "out" / "keyframes.json").read_text())
    assert text == expected == record["keyframes"]
    assert record["params"] == {**sampler_parameters("msa"), "window": 8} and record["frames"] == 60
    assert record["params"]["lambda_u"] == 3.0 and record["params"]["mode"] == "exact"  # the defaults used
    assert (path / "out" / "keyframes.png").read_bytes()[:4] == b"\x89PNG"


def test_tum_poses_give_the_same_keyframes(stream):
    path, _, _ = stream
    a = invoke("--poses", path / "poses.txt", "--descriptors", path / "desc.npy", "--out", path / "a")
    b = invoke("--poses", path / "poses_tum.txt", "--descriptors", path / "desc.npy", "--out", path / "b")
    assert a.exit_code == b.exit_code == 0
    assert (path / "a" / "keyframes.txt").read_text() == (path / "b" / "keyframes.txt").read_text()


def test_flush_is_reported_apart(stream):
    path, _, _ = stream
    result = invoke("--poses", path / "poses.txt", "--descriptors", path / "desc.npy", "--flush", "--out", path / "out")
    record = json.loads((path / "out" / "keyframes.json").read_text())
    assert result.exit_code == 0
    assert record["keyframes"] == record["online_keyframes"] + record["flushed_keyframes"]


def test_point_based_sampler_reads_clouds(stream):
    path, _, _ = stream
    result = invoke(
        "--poses",
        path / "poses.txt",
        "--clouds",
        path / "clouds.npy",
        "--sampler",
        "spaciousness",
        "--out",
        path / "out",
    )
    assert result.exit_code == 0, result.output
    assert json.loads((path / "out" / "keyframes.json").read_text())["keyframes"][0] == 0


def test_a_descriptor_stack_is_not_taken_for_clouds(stream):
    """A (N, 20, 60) Scan Context stack passed as --clouds would give 60 "coordinates" a point."""
    path, _, desc = stream
    np.save(path / "stack.npy", np.zeros((len(desc), 20, 60)))
    result = invoke(
        "--poses", path / "poses.txt", "--clouds", path / "stack.npy", "--sampler", "entropy", "--out", path / "out"
    )
    expect_error(result, "clouds must have shape (N, P, 3) (x y z) or (N, P, 4) (x y z intensity), got ")
    assert not (path / "out").exists()


def expect_error(result, fragment):
    assert result.exit_code != 0
    assert isinstance(result.exception, InputError), result.output
    assert fragment in str(result.exception)


def test_mismatched_descriptor_count_names_the_file(stream):
    path, _, desc = stream
    np.save(path / "short.npy", desc[:-1])
    expect_error(
        invoke("--poses", path / "poses.txt", "--descriptors", path / "short.npy", "--out", path / "o"),
        "short.npy has 59 frames, the sequence has 60",
    )


def test_nan_pose_names_the_line(stream):
    path, _, _ = stream
    lines = (path / "poses.txt").read_text().splitlines()
    lines[7] = lines[7].replace(lines[7].split()[3], "nan", 1)
    (path / "bad.txt").write_text("\n".join(lines) + "\n")
    expect_error(
        invoke("--poses", path / "bad.txt", "--descriptors", path / "desc.npy", "--out", path / "o"),
        "bad.txt:8: pose has NaN",
    )


def test_non_rigid_pose_and_bad_lines(stream):
    path, _, _ = stream
    (path / "scaled.txt").write_text("2 0 0 0 0 1 0 0 0 0 1 0\n")
    expect_error(
        invoke("--poses", path / "scaled.txt", "--descriptors", path / "desc.npy", "--out", path / "o"),
        "not a rigid transform",
    )
    (path / "short.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0\n")
    expect_error(
        invoke("--poses", path / "short.txt", "--descriptors", path / "desc.npy", "--out", path / "o"),
        "short.txt:2: 3 values, expected 12",
    )


def test_tum_times_that_do_not_increase_are_refused(stream):
    """read_poses checks the times (sample does not use them), naming the pose and its line in the file."""
    path, _, _ = stream
    lines = (path / "poses_tum.txt").read_text().splitlines()
    for name, edit, message in (
        ("back.txt", lambda t: t[3] - 0.5, r"pose 5: time \S+ is before the previous one \(\S+ on line 4\) on line 5"),
        ("same.txt", lambda t: t[3], r"pose 5: time \S+ repeats the previous one \(\S+ on line 4\) on line 5"),
        ("nan.txt", lambda t: float("nan"), "pose 5: time nan is not a finite number on line 5"),
    ):
        times = [float(line.split()[0]) for line in lines]
        changed = lines[:4] + [" ".join([repr(edit(times))] + lines[4].split()[1:])] + lines[5:]
        (path / name).write_text("\n".join(changed) + "\n")
        result = invoke("--poses", path / name, "--descriptors", path / "desc.npy", "--out", path / "o")
        assert isinstance(result.exception, InputError) and re.search(f"{name}: {message}", str(result.exception))
        assert not (path / "o").exists()


def test_missing_and_corrupt_files(stream):
    path, _, _ = stream
    expect_error(
        invoke("--poses", path / "nope.txt", "--descriptors", path / "desc.npy", "--out", path / "o"),
        "nope.txt: pose file not found",
    )
    (path / "corrupt.npy").write_bytes(b"not numpy")
    expect_error(
        invoke("--poses", path / "poses.txt", "--descriptors", path / "corrupt.npy", "--out", path / "o"),
        "corrupt.npy is not a .npy file (no NumPy header)",
    )


def test_unknown_sampler_and_missing_inputs(stream):
    path, _, _ = stream
    expect_error(
        invoke("--poses", path / "poses.txt", "--sampler", "random", "--out", path / "o"),
        "unknown sampler 'random'; available: all, constant, entropy, spaciousness, msa",
    )
    expect_error(invoke("--poses", path / "poses.txt", "--sampler", "entropy", "--out", path / "o"), "needs --clouds")
    expect_error(invoke("--poses", path / "poses.txt", "-p", "window", "--out", path / "o"), "expected key=value")
    assert not (path / "o").exists()


@pytest.mark.parametrize(
    "override, fragment",
    [
        ("window=abc", "sampler 'msa': window='abc' is not allowed; expected an integer >= 3"),
        ("alpha=.nan", "sampler 'msa': alpha=nan is not allowed; expected a finite number > 0"),
        ("beta=.inf", "sampler 'msa': beta=inf is not allowed; expected a finite number > 0"),
        ("use_rho=maybe", "sampler 'msa': use_rho='maybe' is not allowed; expected true or false"),
        ("lambda_u=inf", "sampler 'msa': lambda_u='inf' is not allowed; expected a finite number > 0"),
        ("window=30", "window=30: up to 2^29 - 2 = 536870910 candidates per window optimisation, more than the limit"),
    ],
)
def test_bad_sampler_parameter_is_one_clear_error_before_any_work(stream, override, fragment):
    path, _, _ = stream
    expect_error(
        invoke("--poses", path / "poses.txt", "--descriptors", path / "desc.npy", "-p", override, "--out", path / "o"),
        fragment,
    )
    assert not (path / "o").exists()


def test_constant_distance_must_be_a_number(stream):
    path, _, _ = stream
    expect_error(
        invoke("--poses", path / "poses.txt", "--sampler", "constant", "-p", "distance=abc", "--out", path / "o"),
        "sampler 'constant': distance='abc' is not allowed; expected a finite number >= 0",
    )


def test_window_longer_than_the_stream_warns(stream):
    path, poses, desc = stream
    np.save(path / "short.npy", desc[:6])
    write_poses(path / "short.txt", poses[:6], "kitti")
    with pytest.warns(UserWarning, match=r"window=10 is longer than the stream \(6 frames\)"):
        result = invoke(
            "--poses", path / "short.txt", "--descriptors", path / "short.npy", "--flush", "--out", path / "out"
        )
    assert result.exit_code == 0, result.output


def test_stats_report_ambiguous_windows(stream):
    path, _, _ = stream
    np.save(path / "flat.npy", np.zeros((60, 4)))  # every candidate has the same rho: every window is a tie
    result = invoke(
        "--poses",
        path / "poses.txt",
        "--descriptors",
        path / "flat.npy",
        "-p",
        "use_pi=false",
        "-p",
        "window=6",
        "--out",
        path / "out",
    )
    stats = json.loads((path / "out" / "keyframes.json").read_text())["stats"]
    assert result.exit_code == 0, result.output
    assert stats["ambiguous_windows"] == stats["window_optimisations"] == len(stats["ambiguous_frames"]) > 0


def test_parameter_given_twice_is_refused(stream):
    path, _, _ = stream
    expect_error(
        invoke(
            "--poses",
            path / "poses.txt",
            "--descriptors",
            path / "desc.npy",
            "-p",
            "window=8",
            "-p",
            "window=9",
            "--out",
            path / "o",
        ),
        "--param window given twice (8 and 9)",
    )
