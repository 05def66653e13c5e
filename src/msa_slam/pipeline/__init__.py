"""Batch and online SLAM pipelines (the paper's Table I and Table II protocols) over the shared core
(msa_slam.slam), the method comparison and the result folders."""

from msa_slam.pipeline.batch import run_batch
from msa_slam.pipeline.compare import PAPER_METHODS, run_compare
from msa_slam.pipeline.config import RunConfig, apply_params, load_config, make_config
from msa_slam.pipeline.frontend import Frontend, prepare_frontend
from msa_slam.pipeline.results import write_run
from msa_slam.slam import LoopClosure, RunResult

__all__ = ["PAPER_METHODS", "RunConfig", "Frontend", "LoopClosure", "RunResult", "apply_params", "load_config",
           "make_config", "prepare_frontend", "run_batch", "run_compare", "write_run"]
