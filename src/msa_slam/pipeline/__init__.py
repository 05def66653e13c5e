"""Batch SLAM pipeline (the paper's Table I protocol): one sampler per run, or the paper's method set."""

from msa_slam.pipeline.batch import BatchResult, run_batch, sample_keyframes
from msa_slam.pipeline.compare import PAPER_METHODS, run_compare
from msa_slam.pipeline.config import BatchConfig, apply_params, load_config, make_config
from msa_slam.pipeline.frontend import Frontend, prepare_frontend
from msa_slam.pipeline.loops import LoopCandidate, LoopSearch
from msa_slam.pipeline.results import write_run

__all__ = ["PAPER_METHODS", "BatchConfig", "BatchResult", "Frontend", "LoopCandidate", "LoopSearch", "apply_params",
           "load_config", "make_config", "prepare_frontend", "run_batch", "run_compare", "sample_keyframes", "write_run"]
