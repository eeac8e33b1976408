"""The locked install: exact versions with sha256 hashes, solved by uv from pyproject.toml's ranges.

    .venv/bin/python tools/lock.py              # re-solve after editing pyproject.toml (pins that still fit stay)
    .venv/bin/python tools/lock.py --check      # exit 1 when a lock does not satisfy pyproject.toml (offline)
    .venv/bin/python tools/lock.py --upgrade    # the newest releases, measured before and after (docs/install.md)

The locks (:data:`LOCKS`): ``requirements.lock``, what ``tools/setup.sh`` installs (mocapdb's dependencies
with its test and tools extras, the build backend and pip; every platform and Python >= 3.11), and CI's own
under ``.ci/``: the same set with OpenCV 4 (the project runs on OpenCV 4 and 5) and the Blender and
OpenSim wheels of the round-trip tests. ``--upgrade`` runs the tests, the accuracy gate and the runtime
benchmark, upgrades every lock and the virtual environment, runs them again and writes what moved to
``lock_upgrade.md`` for the commit message.
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import tempfile
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VENV_PYTHON = ROOT / ".venv" / "bin" / "python"
PYPROJECT = ROOT / "pyproject.toml"
EXTRAS = ("test", "tools")  # the extras tools/setup.sh installs
REPORT = ROOT / "lock_upgrade.md"


@dataclass(frozen=True)
class Lock:
    """One lock file: what it is solved from, and for which interpreters and platforms."""

    path: str                        # relative to the repository
    project: bool                    # pyproject.toml (with EXTRAS) among the inputs
    requirements: tuple[str, ...]    # further inputs, one requirement each
    universal: bool                  # every platform and Python >= 3.11; else CI's (Linux x86_64, Python 3.11)


# uv ignores the upper bound of a package's Requires-Python: releases that declare they do not run on 3.11
PYTHON_311_CAPS = ("backports-strenum<1.3",)  # 1.3.1 declares Python < 3.11 (ai-edge-litert needs it)


def project_inputs() -> tuple[str, ...]:
    """pyproject.toml's build backend and pip (locked too: the editable install runs without build isolation)
    and :data:`PYTHON_311_CAPS`."""
    return tuple(tomllib.loads(PYPROJECT.read_text())["build-system"]["requires"]) + ("pip>=24",) + PYTHON_311_CAPS


LOCKS = (
    Lock("requirements.lock", True, project_inputs(), universal=True),
    Lock(".ci/opencv4.lock", True, project_inputs() + ("opencv-python-headless<5",), universal=False),
    Lock(".ci/blender.lock", False, ("bpy",), universal=False),
    Lock(".ci/opensim.lock", False, ("opensim", "numpy"), universal=False),
)


def uv() -> str:
    """The uv of the virtual environment (the test extra installs it)."""
    path = VENV_PYTHON.parent / "uv"
    if not path.exists():
        raise SystemExit(f"lock: no {path} (bash tools/setup.sh installs it with the test extra)")
    return str(path)


def compile_lock(lock: Lock, upgrade: bool) -> None:
    """Solve ``lock`` with ``uv pip compile`` (pins of the existing file kept unless ``upgrade``)."""
    with tempfile.NamedTemporaryFile("w", suffix=".in") as inputs:
        inputs.write("\n".join(lock.requirements) + "\n")
        inputs.flush()
        command = [uv(), "pip", "compile", *([str(PYPROJECT)] if lock.project else []), inputs.name,
                   "--generate-hashes", "--python-version", "3.11", "--quiet", "-o", str(ROOT / lock.path),
                   "--custom-compile-command", f"python tools/lock.py{' --upgrade' if upgrade else ''}"]
        command += [arg for extra in EXTRAS for arg in ("--extra", extra)] if lock.project else []
        command += ["--universal"] if lock.universal else ["--python-platform", "x86_64-manylinux_2_28"]
        command += ["--upgrade"] if upgrade else []
        subprocess.run(command, cwd=ROOT, check=True)
    text = (ROOT / lock.path).read_text()  # uv names the temporary input file in its annotations
    (ROOT / lock.path).write_text(text.replace(inputs.name, "tools/lock.py"))


# --- --check: the locks against pyproject.toml, offline --------------------------------------------

PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)(\[[^\]]*\])?==([^\s;\\]+)\s*(;[^\\]*)?\\?$")


def pins(text: str) -> list[tuple[str, str, str]]:
    """(normalised name, version, marker) of every pinned line of a lock's text."""
    found = []
    for line in text.splitlines():
        match = PIN.match(line.strip())
        if match:
            found.append((normalise(match.group(1)), match.group(3), (match.group(4) or "").lstrip("; ").strip()))
    return found


def normalise(name: str) -> str:
    """A distribution name as PEP 503 compares it."""
    return re.sub(r"[-_.]+", "-", name).lower()


def unhashed(text: str) -> list[str]:
    """The pinned lines of a lock's text with no ``--hash`` after them."""
    lines = text.splitlines()
    return [line.strip() for i, line in enumerate(lines) if PIN.match(line.strip())
            and not (i + 1 < len(lines) and lines[i + 1].strip().startswith("--hash=sha256:"))]


def project_requirements() -> list[str]:
    """pyproject.toml's dependencies and the requirements of :data:`EXTRAS`."""
    project = tomllib.loads(PYPROJECT.read_text())["project"]
    return list(project["dependencies"]) + [r for extra in EXTRAS for r in project["optional-dependencies"][extra]]


def lock_problems(lock: Lock) -> list[str]:
    """Why ``lock`` does not satisfy its inputs (missing, outside the range, unhashed); empty when it does.
    Checked for CPython 3.11 on Linux, the interpreter setup.sh and CI use."""
    from packaging.markers import Marker, default_environment
    from packaging.requirements import Requirement

    path = ROOT / lock.path
    if not path.is_file():
        return [f"{lock.path}: missing (python tools/lock.py)"]
    text = path.read_text()
    environment = default_environment() | {"python_version": "3.11", "python_full_version": "3.11.7",
                                           "sys_platform": "linux", "platform_system": "Linux"}
    versions = {name: version for name, version, marker in pins(text)
                if not marker or Marker(marker).evaluate(environment)}
    problems = [f"{lock.path}: {line} has no hash" for line in unhashed(text)]
    wanted = (project_requirements() if lock.project else []) + list(lock.requirements)
    for requirement in map(Requirement, wanted):
        if requirement.marker and not requirement.marker.evaluate(environment):
            continue
        version = versions.get(normalise(requirement.name))
        if version is None:
            problems.append(f"{lock.path}: {requirement.name} is not locked")
        elif not requirement.specifier.contains(version, prereleases=True):
            problems.append(f"{lock.path}: {requirement.name}=={version} is outside {requirement}")
    return problems


# --- --upgrade: measured before and after -----------------------------------------------------------

def run_step(command: list[str], log: Path) -> str:
    """Run ``command`` in the repository, its output to ``log``; the output's last line (its summary)."""
    run = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    log.write_text(run.stdout + run.stderr)
    lines = [line for line in (run.stdout + run.stderr).splitlines() if line.strip()]
    return f"exit {run.returncode}: {lines[-1] if lines else '(no output)'}"


def measure(label: str, work: Path) -> dict:
    """The tests' summary, the accuracy gate's figures and the runtime benchmark's output, as of now."""
    print(f"lock: measuring {label} (tests, accuracy gate, runtime benchmark; about 15 minutes)", flush=True)
    gate_json = work / f"gate_{label}.json"
    python = str(VENV_PYTHON)
    result = {"tests": run_step([python, "-m", "pytest", "-q"], work / f"tests_{label}.log"),
              "gate": run_step([python, "tools/accuracy_gate.py", "--json", str(gate_json)],
                               work / f"gate_{label}.log"),
              "bench": run_step([python, "tools/bench_runtime.py", "--db", "demo/sample.db", "--no-exact"],
                                work / f"bench_{label}.log")}
    result["figures"] = json.loads(gate_json.read_text()) if gate_json.is_file() else {}
    return result


def moved_figures(before: dict[str, float], after: dict[str, float], tolerance: float = 1e-6) -> list[str]:
    """``name: before -> after`` for every figure that changed by more than ``tolerance`` (relative)."""
    return [f"{name}: {before.get(name)} -> {after.get(name)}" for name in sorted(set(before) | set(after))
            if name not in before or name not in after
            or abs(after[name] - before[name]) > tolerance * max(1.0, abs(before[name]))]


def moved_versions(before: str, after: str) -> list[str]:
    """``name old -> new`` for every pin of a lock's text that changed (markers kept apart)."""
    old = {(name, marker): version for name, version, marker in pins(before)}
    new = {(name, marker): version for name, version, marker in pins(after)}
    keys = sorted(key for key in set(old) | set(new) if old.get(key) != new.get(key))
    return [f"{name}{f' ({marker})' if marker else ''}: {old.get(key, '-')} -> {new.get(key, '-')}"
            for key in keys for name, marker in [key]]


def upgrade() -> int:
    """Measure, upgrade the locks and .venv, measure again, write :data:`REPORT`; 0 when tests and gate pass after."""
    work = Path(tempfile.mkdtemp(prefix="mocapdb-lock-"))
    before = measure("before", work)
    old_texts = {lock.path: (ROOT / lock.path).read_text() for lock in LOCKS if (ROOT / lock.path).is_file()}
    for lock in LOCKS:
        compile_lock(lock, upgrade=True)
    subprocess.run([str(VENV_PYTHON), "-m", "pip", "install", "--quiet", "--require-hashes", "-r",
                    str(ROOT / "requirements.lock")], cwd=ROOT, check=True)
    after = measure("after", work)
    lines = ["# Lock upgrade", ""]
    for lock in LOCKS:
        lines += [f"## {lock.path}", ""] + (moved_versions(old_texts.get(lock.path, ""), (ROOT / lock.path).read_text())
                                             or ["(nothing moved)"]) + [""]
    lines += ["## Measured", ""] + [f"{step}: {before[step]} -> {after[step]}" for step in ("tests", "gate", "bench")]
    lines += ["", "gate figures that moved:"] + (moved_figures(before["figures"], after["figures"]) or ["(none)"])
    lines += ["", f"logs (the benchmark's full output among them): {work}"]
    REPORT.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if after["tests"].startswith("exit 0") and after["gate"].startswith("exit 0") else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true", help="check the locks against pyproject.toml (nothing fetched)")
    mode.add_argument("--upgrade", action="store_true", help="newest releases, measured before and after")
    args = parser.parse_args(argv)
    if args.check:
        problems = [problem for lock in LOCKS for problem in lock_problems(lock)]
        print("\n".join(problems) or f"lock: {len(LOCKS)} locks satisfy pyproject.toml")
        return 1 if problems else 0
    if args.upgrade:
        return upgrade()
    for lock in LOCKS:
        compile_lock(lock, upgrade=False)
        print(f"lock: {lock.path} solved")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
