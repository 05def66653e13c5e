"""`msa-slam reproduce --quick` end to end (slow: minutes; `make test-slow`, and a stage of .ci/run)."""

from __future__ import annotations

import pytest
from helpers.cli import run_cli

from msa_slam.experiments.reproduce_report import missing_parts


@pytest.mark.slow
def test_quick_reproduction_writes_every_section_and_the_claims(tmp_path):
    out = tmp_path / "reproduce"
    result = run_cli("reproduce", "--quick", "--quiet", "--out", str(out), timeout=None)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip() == str(out / "report.md")
    assert missing_parts((out / "report.md").read_text()) == []
    assert (out / "figures" / "fig5_deviations.png").is_file()
