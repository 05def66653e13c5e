"""Online pipeline (iSAM2) on small scans simulated in memory (the figure-eight, whose crossing and closure
are revisits), with drifting odometry from ground truth plus seeded noise, so no KISS-ICP is needed. The scans are the
simulator's clean ones: these tests are about the pipeline, not the sensor model's imperfections."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

import numpy as np
import pytest
from helpers.metrics import metrics_json
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.datasets import Frame, SourceOptions
from msa_slam.descriptors import make_descriptor
from msa_slam.errors import InputError
from msa_slam.io.staging import WRITER
from msa_slam.odometry import NoisyOdometry
from msa_slam.pipeline import LiveFrontEnd, run
from msa_slam.pipeline.config import make_online_config
from msa_slam.pipeline.live import STEPS
from msa_slam.registration import DiskCloudStore, downsample
from msa_slam.sampling import make_sampler
from msa_slam.sources import open_source
from msa_slam.types import FrameSource

EIGHT = "live:figure-eight,stride=2,azimuth_steps=360,realism=clean"
COARSE = "live:figure-eight,stride=4,azimuth_steps=180,realism=clean"
NOISE = {"translation_noise": 0.02, "rotation_noise_deg": 0.1}


@pytest.fixture(scope="module")
def msa_run():
    cfg = make_online_config(dataset=EIGHT, odometry="gt-noise", odometry_params=NOISE, sampler="msa")
    return run(cfg)


@pytest.fixture(scope="module")
def coarse_runs(tmp_path_factory):
    store = tmp_path_factory.mktemp("store")
    base = dict(dataset=COARSE, odometry="gt-noise", odometry_params=NOISE, sampler="all", min_frame_gap=20)
    return (
        run(make_online_config(base)),
        run(make_online_config(base, cloud_store="disk", store_dir=str(store))),
        store,
    )


def test_online_msa_finds_loops_and_reduces_ate(msa_run):
    m = metrics_json(msa_run)
    assert 0 < m["keyframes"] < m["frames"] == 214
    assert m["verified"] >= 3 and m["false_loops"] == 0  # oracle mode verifies only true revisits
    assert m["after"]["ate_translation_m"] < 0.8 * m["before"]["ate_translation_m"]
    assert m["improvement_pct"]["translation"] > 20
    assert m["f1_max"] is not None and 0 < m["f1_max"] <= 1
    assert list(msa_run.keyframes) == sorted(msa_run.keyframes)
    assert len(msa_run.optimised) == m["keyframes"]


def test_online_memory_accounting_is_monotone_and_matches_totals(msa_run):
    mem, m = msa_run.memory, metrics_json(msa_run)
    for key in ("keyframes", "cloud_bytes", "descriptor_bytes", "graph_bytes"):
        assert np.all(np.diff(mem[key]) >= 0), key
    assert mem["keyframes"][-1] == m["keyframes"]
    assert m["memory_bytes"]["total"] == mem["cloud_bytes"][-1] + mem["descriptor_bytes"][-1] + mem["graph_bytes"][-1]
    assert m["bytes_per_keyframe"] == pytest.approx(m["memory_bytes"]["total"] / m["keyframes"])
    assert (mem["rss_bytes"] > 0).all() and m["peak_rss_bytes"] >= mem["rss_bytes"].max() * 0.99
    # the sampler's pending frames are forgotten: the buffer never holds more than ~a window of scans
    scan_bytes = mem["pending_bytes"][mem["pending_bytes"] > 0].min()
    assert mem["pending_bytes"].max() <= 16 * scan_bytes


def test_online_step_times_and_latency(msa_run):
    m = metrics_json(msa_run)
    for step in STEPS:
        assert msa_run.steps_ms[step].shape == (214,) and (msa_run.steps_ms[step] >= 0).all()
    new_kf = np.diff(msa_run.memory["keyframes"], prepend=0) > 0
    assert (msa_run.steps_ms["graph_update"][~new_kf] == 0).all()  # iSAM2 runs only when keyframes arrive
    assert (msa_run.steps_ms["graph_update"][new_kf] > 0).all()
    lat = m["latency_ms"]["backend"]
    assert lat["p50"] <= lat["p95"] <= lat["p99"] <= lat["max"]
    assert m["backend_fps"] == pytest.approx(214 / (m["time_s"]["backend_total"]), rel=0.05)
    # the whole pipeline as it ran (the live source simulating each frame too), not only the steps' sum
    processing = m["time_s"]["backend_total"] + m["time_s"]["odometry"] + m["time_s"]["descriptor"]
    assert m["fps"] == pytest.approx(214 / m["pipeline_time_s"], rel=1e-3) and m["pipeline_time_s"] > processing
    # sim:test keeps every other simulated scan: 0.2 s apart, so real time is 5 frames a second, not the 10 Hz default
    assert m["frame_rate_from"] == "timestamps" and m["frame_rate_hz"] == pytest.approx(5.0)
    assert m["realtime_factor"] == pytest.approx(m["fps"] / 5.0)


def test_disk_store_gives_the_same_run_without_clouds_in_ram(coarse_runs):
    memory, disk, store = coarse_runs
    assert memory.keyframes.tolist() == disk.keyframes.tolist()
    pairs = lambda run: [(c.query, c.match, c.accepted) for c in run.loops]  # noqa: E731
    assert pairs(memory) == pairs(disk)
    assert metrics_json(memory)["verified"] > 0
    np.testing.assert_allclose(memory.optimised, disk.optimised, atol=1e-6)
    assert disk.memory["cloud_bytes"].max() == 0
    on_disk = metrics_json(disk)["memory_bytes"]["keyframe_clouds_on_disk"]
    assert on_disk == metrics_json(memory)["memory_bytes"]["keyframe_clouds"]
    assert list(store.iterdir()) == []  # the clouds' folder went at the end of the run; store_dir itself stays


def test_disk_cloud_store_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    points = rng.uniform(-20, 20, (5000, 3))
    store = DiskCloudStore(0.5, tmp_path)
    stored = store.add(7, points)
    np.testing.assert_array_equal(store[7], downsample(points, 0.5))
    assert isinstance(store[7], np.memmap)
    assert 7 in store and len(store) == 1 and store.nbytes == 0 and store.disk_bytes == stored.nbytes
    with pytest.raises(InputError, match="keyframe 8 has no stored cloud"):
        store[8]


def _pausing_source(pause: int) -> tuple[FrameSource, list[Frame], list[int]]:
    """The first 30 scans of COARSE with a stop of `pause` frames at frame 4 (same pose, a fresh scan array
    each frame, as a sensor gives); also the 30 scans and which one each frame shows."""
    scans = [f for _, f in zip(range(30), open_source(COARSE).frames())]
    order = list(range(5)) + [4] * pause + list(range(5, 30))
    gt = np.stack([scans[k].gt_pose for k in order])
    frames = lambda: (Frame(i, i / 10, scans[k].points.copy(), gt[i]) for i, k in enumerate(order))  # noqa: E731
    return FrameSource("pause", gt, frames), scans, order


def test_pending_scans_stay_bounded_while_standing_still():
    """A robot that stops: frames the MSA window skips cannot become keyframes and are not kept, so pending
    data stays within a window of scans, and the keyframes are those of the sampler run on its own."""
    window = 10
    source, scans, order = _pausing_source(pause=300)
    cfg = make_online_config(
        dataset=COARSE,
        odometry="gt-noise",
        sampler="msa",
        sampler_params={"window": window},
        odometry_params={"translation_noise": 0.0, "rotation_noise_deg": 0.0},
    )
    result = run(cfg, LiveFrontEnd(source))
    descriptor = make_descriptor(cfg.descriptor, **cfg.descriptor_params)
    descriptors = [np.asarray(descriptor.compute(s.points, frame=k), dtype=np.float64) for k, s in enumerate(scans)]
    largest_scan = max(s.points.nbytes for s in scans) + descriptors[0].nbytes
    pending = result.memory["pending_bytes"]
    assert pending.max() > 0 and pending.max() <= (window + 1) * largest_scan
    alone = make_sampler("msa", window=window).run(
        source.gt_poses, np.stack([descriptors[k] for k in order]), flush=True
    )
    assert result.keyframes.tolist() == sorted(alone) and result.keyframes[-1] > 300


def test_disk_store_folder_is_private_and_removed_on_close(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the system temp folder, for this test
    store = DiskCloudStore(0.5)
    store.add(1, np.random.default_rng(0).uniform(-20, 20, (500, 3)))
    assert store.folder.parent == tmp_path and store.folder.name.startswith(f"msa-kf-clouds-{os.getpid()}-")
    assert [p.name for p in store.folder.iterdir() if p.name != WRITER] == ["kf_1.npy"]
    store.close()
    assert list(tmp_path.iterdir()) == []
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    created = tmp_path / "new" / "deeper"
    for parent in (user, created):
        store = DiskCloudStore(0.5, parent)
        store.add(1, np.random.default_rng(0).uniform(-20, 20, (500, 3)))
        store.close()
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["notes.txt", "user"]  # made for the store: gone


def test_online_run_removes_its_cloud_folder_even_when_it_fails(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    base = dict(dataset=COARSE, odometry="gt-noise", cloud_store="disk", max_frames=40)
    run(make_online_config(base, sampler="constant", sampler_params={"distance": 2.0}))
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="kept only 1 of") as failed:
        run(make_online_config(base, sampler="constant", sampler_params={"distance": 1e6}))
    assert failed.traceback and list(tmp_path.iterdir()) == []  # closed by the run, not left to the collector


def test_stale_cloud_folders_of_ended_runs_are_removed(tmp_path):
    ended = subprocess.Popen([sys.executable, "-c", "pass"])
    ended.wait()
    stale, live, foreign = (
        tmp_path / f"msa-kf-clouds-{ended.pid}-a",
        tmp_path / f"msa-kf-clouds-{os.getpid()}-b",
        tmp_path / f"msa-kf-clouds-{ended.pid}-c",
    )
    for folder, name in (
        (stale, "kf_3.npy"),
        (stale, ".kf_4.npy.x1y2.tmp"),
        (live, "kf_3.npy"),
        (foreign, "thesis.tex"),
    ):
        folder.mkdir(exist_ok=True)
        (folder / name).write_bytes(b"x")
    (tmp_path / "notes.txt").write_text("mine")
    store = DiskCloudStore(0.5, tmp_path)
    assert not stale.exists()
    assert (live / "kf_3.npy").is_file() and (foreign / "thesis.tex").is_file() and (tmp_path / "notes.txt").is_file()
    store.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, foreign.name, "notes.txt"])


def test_store_dir_that_is_a_file_is_refused(tmp_path):
    (tmp_path / "clouds").write_text("not a folder")
    with pytest.raises(InputError, match="store_dir .*clouds.* is a file"):
        DiskCloudStore(0.5, tmp_path / "clouds")


def test_live_source_laps_drive_back_and_forth():
    one = open_source(COARSE)
    three = open_source(COARSE + ",laps=3")
    assert len(three) == 3 * len(one) and three.name.endswith("-x3")
    np.testing.assert_array_equal(three.gt_poses[len(one) : 2 * len(one)], one.gt_poses[::-1])
    steps = np.linalg.norm(np.diff(three.gt_poses[:, :3, 3], axis=0), axis=1)
    assert steps.max() < 3 * np.median(steps)  # continuous path: no jump between passes
    frame = next(iter(three.frames()))
    assert frame.points.shape[1] == 3 and frame.index == 0


def test_noisy_odometry_is_exact_without_noise_and_seeded_with_it():
    gt = open_source(COARSE).gt_poses[:30]
    exact = NoisyOdometry(gt, 0.0, 0.0)
    np.testing.assert_allclose(np.stack([exact.register() for _ in range(30)]), gt, atol=1e-9)
    a, b = NoisyOdometry(gt, seed=3), NoisyOdometry(gt, seed=3)
    np.testing.assert_array_equal(
        np.stack([a.register() for _ in range(30)]), np.stack([b.register() for _ in range(30)])
    )
    with pytest.raises(InputError, match="frame 30 requested"):
        a.register()


@pytest.mark.parametrize(
    "data, message",
    [
        ({"dataset": EIGHT, "clouds": "disk"}, "unknown key 'clouds'; valid keys: .*cloud_store"),
        ({"dataset": EIGHT, "cloud_store": "ssd"}, "cloud_store"),
        ({"dataset": EIGHT, "verifier": {"gate": 1}}, "unknown key 'verifier.gate'; valid keys: voxel_size"),
    ],
)
def test_online_config_errors(data, message):
    with pytest.raises(InputError, match=message):
        make_online_config(data)


def test_bad_sources_and_odometry_parameters():
    with pytest.raises(InputError, match="laps must be an integer >= 1"):
        open_source("live:figure-eight,laps=0")
    with pytest.raises(InputError, match="unknown simulated sequence 'moon-walk'"):
        open_source("live:moon-walk")
    with pytest.raises(
        InputError,
        match=r"^dataset 'live:figure-eight': --first applies to recordings, not to a live: "
        r"source .*start=, end=, stride=.*-p max_frames=N$",
    ):
        open_source("live:figure-eight", source=SourceOptions(first=100))
    with pytest.raises(
        InputError,
        match=r"^dataset 'live:figure-eight': --loader, --gt, --jump, -n apply to "
        r"recordings",
    ):
        open_source("live:figure-eight", "kitti", source=SourceOptions(gt="poses.txt", jump=2, frames=9))
    cfg = make_online_config(dataset=COARSE, odometry="gt-noise", odometry_params={"drift": 1})
    with pytest.raises(InputError, match="translation_noise, rotation_noise_deg"):
        run(cfg)


def test_online_cli_writes_result_folder(tmp_path):
    out = tmp_path / "run"
    result = CliRunner().invoke(
        app,
        [
            "online",
            "-d",
            COARSE,
            "--odometry",
            "gt-noise",
            "-p",
            "min_frame_gap=20",
            "-p",
            "odometry.translation_noise=0.02",
            "--sampler",
            "constant",
            "-p",
            "distance=2.0",
            "--out",
            str(out),
            "--quiet",
        ],
    )
    assert result.exit_code == 0, result.output
    assert (out / "report.md").is_file() and str(out / "report.md") in result.output
    lines = (out / "steps.csv").read_text().splitlines()
    assert lines[0].startswith("frame,odometry_ms") and len(lines) == 1 + 107
    for name in ("trajectories.png", "memory.png", "step_times.png"):
        assert (out / "figures" / name).is_file()
    assert (out / "trajectories" / "optimised_keyframes.tum").is_file()
    assert "distance: 2.0" in (out / "config.yaml").read_text()


@pytest.mark.slow
def test_long_tour_keeps_memory_bounded(tmp_path):
    """Three passes over the 2.2 km city tour (~3,900 scans): clouds on disk, so RSS grows only by the
    per-keyframe bookkeeping (descriptor, pose, graph), not by the clouds."""
    cfg = make_online_config(
        dataset="live:city-tour,stride=2,azimuth_steps=360,laps=3",
        odometry="gt-noise",
        sampler="msa",
        cloud_store="disk",
        store_dir=str(tmp_path),
    )
    r = run(cfg)
    m, mem = metrics_json(r), r.memory
    assert m["verified"] > 50 and m["false_loops"] == 0
    assert m["after"]["ate_translation_m"] < m["before"]["ate_translation_m"]
    assert mem["cloud_bytes"].max() == 0 and m["memory_bytes"]["keyframe_clouds_on_disk"] > 0
    tenth = len(mem["rss_bytes"]) // 10
    in_ram_per_keyframe = (mem["descriptor_bytes"][-1] + mem["graph_bytes"][-1]) / m["keyframes"]
    growth = mem["rss_bytes"][-1] - mem["rss_bytes"][tenth]
    assert growth < 100 * 2**20 + 4 * in_ram_per_keyframe * m["keyframes"]


def test_online_trajectories_carry_the_frames_own_times(tmp_path):
    """Trajectory files of an online run use each frame's time (it was frame / sensor rate before)."""
    from msa_slam.reporting.results import write_run_files

    scans = [f for _, f in zip(range(40), open_source(COARSE).frames())]
    times = 100.0 + 0.1 * np.arange(40) + 0.03 * (np.arange(40) % 2)  # irregular, not starting at 0
    gt = np.stack([s.gt_pose for s in scans])
    source = FrameSource(
        "timed", gt, lambda: (Frame(i, t, s.points, s.gt_pose) for i, (t, s) in enumerate(zip(times, scans)))
    )
    cfg = make_online_config(dataset=COARSE, odometry="gt-noise", sampler="constant", sampler_params={"distance": 1.0})
    result = run(cfg, LiveFrontEnd(source))
    write_run_files(result, tmp_path, figures=False)
    stamps = np.loadtxt(tmp_path / "trajectories" / "odometry.tum")[:, 0]
    np.testing.assert_allclose(stamps, times, atol=1e-6)
    kf_stamps = np.loadtxt(tmp_path / "trajectories" / "optimised_keyframes.tum")[:, 0]
    np.testing.assert_allclose(kf_stamps, times[result.keyframes], atol=1e-6)


def test_online_samples_on_ground_truth_when_asked():
    """`sample_on: gt` reaches the online pipeline (it sampled odometry poses whatever the setting)."""
    frames = [f for _, f in zip(range(60), open_source(COARSE).frames())]
    source = FrameSource("first-60", np.stack([f.gt_pose for f in frames]), lambda: iter(frames))
    noisy = {"translation_noise": 0.3, "rotation_noise_deg": 2.0}
    cfg = make_online_config(
        dataset=COARSE, odometry="gt-noise", odometry_params=noisy, sampler="constant", sampler_params={"distance": 2.0}
    )
    expected = sorted(make_sampler("constant", distance=2.0).run(source.gt_poses, None, flush=True))
    on_gt = run(cfg.model_copy(update={"sample_on": "gt"}), LiveFrontEnd(source))
    on_odometry = run(cfg, LiveFrontEnd(source))
    assert on_gt.keyframes.tolist() == expected
    assert on_odometry.keyframes.tolist() != expected  # the noisy odometry moves differently


def test_rss_growth_is_measured_from_backend_start_to_its_end(monkeypatch):
    """rss_growth_bytes is the RSS after the final optimisation minus the RSS when the back-end was built."""
    import msa_slam.slam.backend as backend_module

    readings = iter([100 * 2**20, 175 * 2**20])
    monkeypatch.setattr(backend_module, "current_rss_bytes", lambda: next(readings))
    source, _, _ = _pausing_source(pause=0)
    cfg = make_online_config(dataset=COARSE, odometry="gt-noise", sampler="constant", sampler_params={"distance": 2.0})
    metrics = metrics_json(run(cfg, LiveFrontEnd(source)))
    assert metrics["rss_growth_bytes"] == 75 * 2**20
    assert metrics["memory_bytes"]["total"] > 0
