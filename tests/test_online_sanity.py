"""The online pipeline runs the batch pipeline's plausibility checks on its odometry (it ran none)."""

from __future__ import annotations

import numpy as np
from helpers.metrics import metrics_json

from msa_slam.datasets import Frame
from msa_slam.pipeline import LiveFrontEnd, run
from msa_slam.pipeline.config import make_online_config
from msa_slam.sources import open_source
from msa_slam.types import FrameSource

COARSE = "live:figure-eight,stride=4,azimuth_steps=180,realism=clean"


def test_online_run_warns_about_a_teleporting_ground_truth(caplog):
    """Ground truth that jumps 80 m between two frames (gt-noise odometry follows it) is reported in
    metrics `warnings` and in the log, as the batch pipeline reports it."""
    scans = [f for _, f in zip(range(60), open_source(COARSE).frames())]
    gt = np.stack([s.gt_pose for s in scans])
    gt[30:, 0, 3] += 80.0
    source = FrameSource("teleport", gt, lambda: (Frame(i, s.time, s.points, gt[i]) for i, s in enumerate(scans)))
    cfg = make_online_config(dataset=COARSE, odometry="gt-noise", sampler="constant", sampler_params={"distance": 1.0})
    warnings = metrics_json(run(cfg, LiveFrontEnd(source)))["warnings"]
    assert any(w.startswith("ground truth: 1 implausible step") and "frames 29 -> 30" in w for w in warnings)
    assert any(w.startswith("odometry: 1 implausible step") for w in warnings)
    assert "ground truth: 1 implausible step" in caplog.text


def test_online_run_without_implausible_motion_has_no_odometry_warning():
    scans = [f for _, f in zip(range(60), open_source(COARSE).frames())]
    source = FrameSource("calm", np.stack([s.gt_pose for s in scans]), lambda: iter(scans))
    cfg = make_online_config(dataset=COARSE, odometry="gt-noise", sampler="constant", sampler_params={"distance": 1.0})
    warnings = metrics_json(run(cfg, LiveFrontEnd(source)))["warnings"]
    assert not [w for w in warnings if w.startswith(("odometry:", "ground truth:"))]
