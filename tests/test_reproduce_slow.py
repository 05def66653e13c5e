"""`msa-slam reproduce --quick` end to end (slow: minutes; `make test-slow`, and a stage of .ci/run)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from msa_slam.experiments.reproduce_report import missing_parts


@pytest.mark.slow
def test_quick_reproduction_writes_every_section_and_the_claims(tmp_path):
    code = "import sys; from msa_slam.cli import main; sys.argv = ['msa-slam', *sys.argv[1:]]; main()"
    out = tmp_path / "reproduce"
    result = subprocess.run(
        [sys.executable, "-c", code, "reproduce", "--quick", "--quiet", "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip() == str(out / "report.md")
    assert missing_parts((out / "report.md").read_text()) == []
    assert (out / "figures" / "fig5_deviations.png").is_file()
