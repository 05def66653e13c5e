"""msa_slam.sources.parse_spec: every dataset spelling the commands accept, and one clear error for a bad one
(naming the spec, the key and the valid keys or values)."""

from __future__ import annotations

import numpy as np
import pytest

from msa_slam.datasets import SourceOptions
from msa_slam.errors import InputError
from msa_slam.io.poses import write_poses
from msa_slam.sim import DEFAULT_CONFIGS, make_config
from msa_slam.sources import SourceSpec, check_selection, parse_spec, resolve_dataset, seeded


def _pose_file(path):
    poses = np.tile(np.eye(4), (20, 1, 1))
    poses[:, 0, 3] = np.arange(20.0)
    write_poses(path, poses)
    return path


@pytest.mark.parametrize(
    "text, kind, name, keys, laps, config",
    [
        ("sim:test", "sim", "test", (), 1, DEFAULT_CONFIGS["test"]),
        ("sim:demo", "sim", "demo", (), 1, DEFAULT_CONFIGS["demo"]),
        ("sim:test,stride=4", "sim", "test", ("stride",), 1, DEFAULT_CONFIGS["test"].model_copy(update={"stride": 4})),
        (
            "sim:kitti-05,stride=3,end=900",
            "sim",
            "kitti-05",
            ("stride", "end"),
            1,
            make_config(trajectory="kitti-05", stride=3, end=900),
        ),
        (
            "sim:trajectory=kitti-07,end=6,realism=kitti-hard",
            "sim",
            "",
            ("trajectory", "end", "realism"),
            1,
            make_config(trajectory="kitti-07", end=6, realism="kitti-hard"),
        ),
        ("live:figure-eight", "live", "figure-eight", (), 1, make_config(trajectory="figure-eight")),
        ("live:city-tour,laps=10", "live", "city-tour", ("laps",), 10, make_config(trajectory="city-tour")),
        (
            "live:figure-eight,start=100,stride=2,azimuth_steps=360",
            "live",
            "figure-eight",
            ("start", "stride", "azimuth_steps"),
            1,
            make_config(trajectory="figure-eight", start=100, stride=2, azimuth_steps=360),
        ),
    ],
)
def test_simulated_spellings(text, kind, name, keys, laps, config):
    spec = parse_spec(text)
    assert (spec.text, spec.kind, spec.name, spec.keys, spec.laps, spec.path) == (text, kind, name, keys, laps, None)
    assert spec.simulated and spec.config == config


def test_a_pose_file_names_the_trajectory_first_or_as_a_key(tmp_path):
    poses = _pose_file(tmp_path / "1e3.txt")  # a path is taken verbatim, not read as the number 1000
    keyed = parse_spec(f"sim:trajectory={poses},end=5")
    assert keyed.name == "" and keyed.config.trajectory == str(poses) and keyed.config.end == 5
    assert keyed.label == "file-1e3"
    for prefix in ("sim:", "live:"):
        first = parse_spec(f"{prefix}{poses},laps=2" if prefix == "live:" else f"{prefix}{poses}")
        assert first.config.trajectory == str(poses) and first.label == str(poses)


@pytest.mark.parametrize(
    "layout, loader",
    [
        (("velodyne/",), "kitti"),
        (("000000.bin", "000001.bin"), "folder"),
        (("a.pcd", "b.pcd"), "folder"),
        (("a.ply",), "folder"),
        (("sensor_data/Ouster/",), "mulran"),
        (("Ouster/",), "mulran"),
        (("metadata.yaml", "bag_0.db3"), "rosbag"),
        (("part_0.bag", "part_1.bag"), "rosbag"),
    ],
)
def test_recorded_folders_and_bags(tmp_path, layout, loader):
    folder = tmp_path / "seq"
    folder.mkdir()
    for entry in layout:
        if entry.endswith("/"):
            (folder / entry).mkdir(parents=True)
        else:
            (folder / entry).write_bytes(b"")
    spec = parse_spec(str(folder))
    assert spec == SourceSpec(str(folder), "recording", path=folder) and not spec.simulated
    assert spec.loader() == loader
    assert resolve_dataset(spec) == folder


def test_a_bag_file_is_a_recording(tmp_path):
    bag = tmp_path / "drive.bag"
    bag.write_bytes(b"")
    assert parse_spec(str(bag)).loader() == "rosbag"


def test_seed_is_substituted_in_grids_only(tmp_path):
    assert seeded("sim:test,seed={seed}", 3) == "sim:test,seed=3"
    assert parse_spec("sim:test,seed={seed}", seed=2).config.seed == 2
    (tmp_path / "0").mkdir()
    assert parse_spec(str(tmp_path / "{seed}"), seed=0).path == tmp_path / "0"
    with pytest.raises(
        InputError,
        match=r"^dataset 'sim:test,seed=\{seed\}': \{seed\} is replaced only in an "
        r"experiment grid's datasets",
    ):
        parse_spec("sim:test,seed={seed}")


SIM_KEYS = (
    "trajectory, trajectory_format, times, calib, sensor, start, end, stride, seed, azimuth_steps, "
    "max_range, range_noise, dropout, style, realism"
)


@pytest.mark.parametrize(
    "text, message",
    [
        ("sim:test,sensr=hdl64", f"dataset 'sim:test,sensr=hdl64': unknown key 'sensr'; valid keys: {SIM_KEYS}"),
        (
            "live:figure-eight,lap=2",
            f"dataset 'live:figure-eight,lap=2': unknown key 'lap'; valid keys: {SIM_KEYS}, laps",
        ),
        ("sim:test,laps=2", f"dataset 'sim:test,laps=2': unknown key 'laps'; valid keys: {SIM_KEYS}"),
        ("sim:test,stride", f"dataset 'sim:test,stride': expected key=value, got 'stride'; valid keys: {SIM_KEYS}"),
        (
            "sim:test,sensor=vlp16",
            "dataset 'sim:test,sensor=vlp16': sensor: unknown sensor 'vlp16'; choose one of hdl64, os1-64, os1-128",
        ),
        ("sim:test,stride=two", "dataset 'sim:test,stride=two': stride: Input should be a valid integer"),
        ("sim:test,stride=2,stride=3", "dataset 'sim:test,stride=2,stride=3': key 'stride' is given twice"),
        ("live:figure-eight,laps=0", "dataset 'live:figure-eight,laps=0': laps must be an integer >= 1, got 0"),
        ("live:figure-eight,laps=yes", "dataset 'live:figure-eight,laps=yes': laps must be an integer >= 1, got True"),
        (
            "sim:atlantis",
            "dataset 'sim:atlantis': unknown simulated sequence 'atlantis'; choose one of demo, test, kitti-00",
        ),
        ("live:moon-walk", "dataset 'live:moon-walk': unknown simulated sequence 'moon-walk'; choose one of demo"),
        ("sim:", "dataset 'sim:': names no simulated sequence; give sim:NAME (one of demo, test"),
        (
            "sim:/nowhere/poses.txt",
            "dataset 'sim:/nowhere/poses.txt': trajectory: pose file not found: '/nowhere/poses.txt'",
        ),
        ("/nowhere/at/all", "dataset '/nowhere/at/all': not found (give a sequence folder, a bag or sim:NAME)"),
    ],
)
def test_bad_specs_are_one_line_naming_spec_and_key(text, message):
    with pytest.raises(InputError) as raised:
        parse_spec(text)
    assert str(raised.value).startswith(message) and "\n" not in str(raised.value)


def test_a_live_source_has_no_folder_and_takes_no_recording_options():
    with pytest.raises(
        InputError,
        match=r"^dataset 'live:figure-eight': a live: source is simulated as `msa-slam "
        r"online` reads it and has no folder",
    ):
        resolve_dataset("live:figure-eight")
    with pytest.raises(InputError, match=r"^dataset 'live:figure-eight': --loader, --sequence apply to recordings"):
        check_selection("live:figure-eight", "folder", SourceOptions(sequence="00"))
    with pytest.raises(InputError, match=r"^dataset 'sim:test': --topic applies to recordings"):
        check_selection(parse_spec("sim:test"), "auto", SourceOptions(topic="/points"))
    check_selection("sim:test", "kitti", SourceOptions(first=10, jump=2))  # a sim: sequence has KITTI's layout
