"""The Python API example of docs/api.md runs as written (outputs redirected to a temporary folder)."""
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _api_example() -> str:
    section = (ROOT / "docs" / "api.md").read_text().split("# Python API", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_api_example_runs(tmp_path):
    code = _api_example()
    assert 'out = Path("demo")' in code
    code = code.replace('out = Path("demo")', f"out = Path({str(tmp_path)!r})")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert (tmp_path / "api.db").is_dir() and list((tmp_path / "api_tracks").glob("track_*.trc"))
    lines = [line.split() for line in run.stdout.splitlines() if re.match(r"\d+ \d+ \[", line)]
    assert len({line[0] for line in lines}) > 50  # a pose in most of the 100 frames


def test_import_mocapdb_is_light_and_lists_the_api():
    code = ("import sys, mocapdb\nassert 'numba' not in sys.modules and 'pyarrow' not in sys.modules\n"
            "print(sorted(n for n in dir(mocapdb) if not n.startswith('_')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert "Engine" in out.stdout and "load_database" in out.stdout
