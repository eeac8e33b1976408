"""Bring three.js into the viewer's vendored code (`mocapdb/view/vendor/three/`) from the npm registry.

    python tools/vendor_three.py            # npm pack three@VERSION, check, copy, write SHA256SUMS
    python tools/vendor_three.py --check    # the bundled files against SHA256SUMS (nothing fetched)

The tarball's sha256 is pinned here; the files copied out of it (the ES module build, its core,
OrbitControls and the MIT licence) are unchanged and listed with their sha256 in SHA256SUMS
(`sha256sum -c SHA256SUMS` in that folder checks them too). `data_specs/viewer.md` records both.
"""
from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

VERSION = "0.187.0"
TARBALL_SHA256 = "ff540832ded0cfe919764d24a3d88f3e2a05f23303f876423e4f893841e90728"
FILES = {  # bundled name: path inside the tarball
    "three.module.js": "package/build/three.module.js",
    "three.core.js": "package/build/three.core.js",
    "OrbitControls.js": "package/examples/jsm/controls/OrbitControls.js",
    "LICENSE": "package/LICENSE",
}
DEST = Path(__file__).resolve().parents[1] / "mocapdb" / "view" / "vendor" / "three"
SUMS = "SHA256SUMS"


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def check(folder: Path = DEST) -> list[str]:
    """The bundled files that do not match SHA256SUMS (empty: all match)."""
    wrong = []
    for line in (folder / SUMS).read_text().splitlines():
        digest, name = line.split(maxsplit=1)
        path = folder / name.lstrip("*")
        if not path.is_file() or sha256(path.read_bytes()) != digest:
            wrong.append(name)
    return wrong


def vendor() -> None:
    """npm pack the pinned version, check the tarball, copy the files, write SHA256SUMS."""
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(["npm", "pack", f"three@{VERSION}", "--silent"], cwd=tmp, check=True, stdout=subprocess.DEVNULL)
        tarball = Path(tmp) / f"three-{VERSION}.tgz"
        if sha256(tarball.read_bytes()) != TARBALL_SHA256:
            sys.exit(f"{tarball.name}: sha256 {sha256(tarball.read_bytes())}, expected {TARBALL_SHA256}")
        DEST.mkdir(parents=True, exist_ok=True)
        lines = []
        with tarfile.open(tarball) as tar:
            for name, member in FILES.items():
                source = tar.extractfile(member)
                assert source is not None, member
                data = source.read()
                (DEST / name).write_bytes(data)
                lines.append(f"{sha256(data)}  {name}")
        (DEST / SUMS).write_text("\n".join(lines) + "\n")
    print(f"three@{VERSION} (tarball sha256 {TARBALL_SHA256}) into {DEST}:")
    print("\n".join(lines))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="check the bundled files only")
    if parser.parse_args().check:
        wrong = check()
        print("\n".join(f"{name}: sha256 differs from {SUMS}" for name in wrong) or f"three@{VERSION}: all files match")
        return 1 if wrong else 0
    vendor()
    return 0


if __name__ == "__main__":
    sys.exit(main())
