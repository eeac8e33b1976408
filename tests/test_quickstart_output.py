"""`tools/quickstart.sh`'s main-job commands (reconstruct and stereo, not the set-up) run on the bundled
data as written (the test database in place of demo/sample.db, the outputs in a temporary folder), with
Python's warnings made errors, and print no warning (issue 52: the demo's first words were warnings)."""
import shlex
import subprocess
import sys

import pytest

from .conftest import ROOT

MAIN_JOBS = ("reconstruct", "stereo")


def _main_job_commands() -> list[list[str]]:
    """The quickstart's `mocapdb reconstruct` and `mocapdb stereo` commands, continuation lines joined."""
    script = (ROOT / "tools" / "quickstart.sh").read_text().replace("\\\n", " ")
    commands = [shlex.split(line) for line in script.splitlines() if line.startswith(".venv/bin/mocapdb ")]
    return [c[1:] for c in commands if c[1] in MAIN_JOBS]


def test_the_quickstart_runs_both_main_jobs():
    assert sorted(c[0] for c in _main_job_commands()) == sorted(MAIN_JOBS)


@pytest.mark.parametrize("command", _main_job_commands(), ids=lambda c: c[0])
def test_the_quickstarts_main_jobs_print_no_warning(command, small_db_path, tmp_path):
    args = [str(small_db_path) if a == "demo/sample.db" else a.replace("demo/", f"{tmp_path}/") for a in command]
    run = subprocess.run([sys.executable, "-W", "error", "-m", "mocapdb", *args], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    lines = (run.stdout + run.stderr).splitlines()
    assert not [line for line in lines if "warning" in line.lower()], lines
