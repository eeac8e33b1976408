"""The BlazePose, hand and face models on this machine: fetched once from the package indexes, checked, converted.

``mocapdb models fetch`` (run by ``tools/setup.sh``) downloads the pinned packages that carry
MediaPipe's BlazePose TFLite files (Apache-2.0), checks the sha256 of the package and of each file
taken from it, converts each with :func:`mocapdb.detect.tflite_onnx.convert_tflite` and writes the
ONNX files with a model card, beside the TFLite originals, into :func:`models_dir`. Nothing is downloaded at run time:
:func:`blazepose_paths` finds the converted files or raises DetectError naming the one command that
prepares them. Sources and pins: ``data_specs/pose_models.md`` ("BlazePose").
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from mocapdb.core.files import write_atomic
from mocapdb.detect.errors import DetectError
from mocapdb.detect.options import (
    BLAZEPOSE_VARIANTS,
    DEFAULT_BLAZEPOSE,
    DEFAULT_HAND_MODEL,
    FACE,
    FETCH_COMMAND,
    HAND_MODELS,
    HANDS,
)


@dataclass(frozen=True)
class Package:
    """A pinned package on a package index that carries model files."""

    index: str        # "pypi" or "npm"
    name: str
    version: str
    file_name: str    # the exact file fetched
    sha256: str
    license: str


MEDIAPIPE_WHEEL = Package(
    "pypi", "mediapipe", "0.10.21", "mediapipe-0.10.21-cp311-cp311-manylinux_2_28_x86_64.whl",
    "05dc4a9e593655a79558d05d6227d31018c2537a4bd3362b51e230cf22aecfe3", "Apache-2.0")
MEDIAPIPE_NPM = Package(
    "npm", "@mediapipe/pose", "0.5.1675469404", "mediapipe-pose-0.5.1675469404.tgz",
    "8bb349a7b3a3ba699df23be804ddd3b3eab810b50b15406894be257859388a84", "Apache-2.0")


@dataclass(frozen=True)
class ModelFile:
    """One TFLite file inside a package, and its sha256."""

    package: Package
    member: str
    sha256: str

    @property
    def stem(self) -> str:
        return Path(self.member).stem


DETECTOR = ModelFile(MEDIAPIPE_WHEEL, "mediapipe/modules/pose_detection/pose_detection.tflite",
                     "9ba9dd3d42efaaba86b4ff0122b06f29c4122e756b329d89dca1e297fd8f866c")
LANDMARKS = {
    "full": ModelFile(MEDIAPIPE_WHEEL, "mediapipe/modules/pose_landmark/pose_landmark_full.tflite",
                      "e9a5c5cb17f736fafd4c2ec1da3b3d331d6edbe8a0d32395855aeb2cdfd64b9f"),
    "lite": ModelFile(MEDIAPIPE_NPM, "package/pose_landmark_lite.tflite",
                      "f17bfbecadb61c3be1baa8b8d851cc6619c870a87167b32848ad20db306b9d61"),
    "heavy": ModelFile(MEDIAPIPE_NPM, "package/pose_landmark_heavy.tflite",
                       "59e42d71bcd44cbdbabc419f0ff76686595fd265419566bd4009ef703ea8e1fe"),
}
# MediaPipe Hands' landmark models (224 x 224; 21 points, hand flag, handedness), both prepared by `models fetch hands`
HAND_LANDMARKS = ModelFile(MEDIAPIPE_WHEEL, "mediapipe/modules/hand_landmark/hand_landmark_full.tflite",
                           "11c272b891e1a99ab034208e23937a8008388cf11ed2a9d776ed3d01d0ba00e3")
HAND_LANDMARKS_LITE = ModelFile(MEDIAPIPE_WHEEL, "mediapipe/modules/hand_landmark/hand_landmark_lite.tflite",
                                "048edd3645c9bf7397d19a9f6e3a42957d6e414c9bea6598030a2e9b624156e6")
HAND_VARIANTS = dict(zip(HAND_MODELS, (HAND_LANDMARKS, HAND_LANDMARKS_LITE)))   # `--hand-model` name → file
# MediaPipe Face Mesh's landmark model (192 x 192; 468 points, face flag), prepared by `models fetch face`
FACE_LANDMARKS = ModelFile(MEDIAPIPE_WHEEL, "mediapipe/modules/face_landmark/face_landmark.tflite",
                           "1055cb9d4a9ca8b8c688902a3a5194311138ba256bcc94e336d8373a5f30c814")
# `models fetch` names beyond the BlazePose variants → the files each prepares
EXTRA_MODELS = {HANDS: tuple(HAND_VARIANTS.values()), FACE: (FACE_LANDMARKS,)}
BLAZEPOSE_AUTHORS = "Google LLC (MediaPipe BlazePose: Bazarevsky et al., 2020, arXiv:2006.10204)"
_HANDS_AUTHORS = "Google LLC (MediaPipe Hands: Zhang et al., 2020, arXiv:2006.10214)"
_AUTHORS = {**{model.stem: _HANDS_AUTHORS for model in HAND_VARIANTS.values()},
            FACE_LANDMARKS.stem: "Google LLC (MediaPipe Face Mesh: Kartynnik et al., 2019, arXiv:1907.06724)"}


def models_dir() -> Path:
    """Where converted models live: ``$MOCAPDB_MODELS``, else ``$XDG_CACHE_HOME/mocapdb/models``
    (``~/.cache/mocapdb/models``)."""
    if os.environ.get("MOCAPDB_MODELS"):
        return Path(os.environ["MOCAPDB_MODELS"])
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "mocapdb" / "models"


def onnx_path(model: ModelFile, folder: Path | None = None) -> Path:
    """The converted file of ``model`` in ``folder`` (default :func:`models_dir`)."""
    return (folder or models_dir()) / f"{model.stem}.onnx"


def tflite_path(model: ModelFile, folder: Path | None = None) -> Path:
    """The TFLite original of ``model`` kept beside its conversion (the reference the tests check it against)."""
    return (folder or models_dir()) / Path(model.member).name


def blazepose_paths(variant: str = DEFAULT_BLAZEPOSE, folder: Path | None = None) -> tuple[Path, Path]:
    """The converted person detector and ``variant`` landmark model; DetectError naming the command
    that prepares them when they are missing."""
    if variant not in LANDMARKS:
        raise DetectError(f"unknown BlazePose variant {variant!r}: one of {', '.join(BLAZEPOSE_VARIANTS)}")
    paths = onnx_path(DETECTOR, folder), onnx_path(LANDMARKS[variant], folder)
    missing = [p for p in paths if not p.is_file()]
    if missing:
        extra = "" if variant == DEFAULT_BLAZEPOSE else f" {variant}"
        raise DetectError(f"BlazePose {variant} is not prepared on this machine ({missing[0]} missing): run "
                          f"`{FETCH_COMMAND}{extra}` once, with access to the package index (it downloads the "
                          f"pinned MediaPipe package and converts its models; nothing is fetched at run time)")
    return paths


def hand_landmark_path(variant: str = DEFAULT_HAND_MODEL, folder: Path | None = None) -> Path:
    """The converted hand landmark model ``variant`` (:data:`HAND_VARIANTS`: full, lite); DetectError naming
    the command that prepares it when missing."""
    if variant not in HAND_VARIANTS:
        raise DetectError(f"unknown hand landmark model {variant!r}: one of {', '.join(HAND_MODELS)}")
    return _prepared(HANDS, HAND_VARIANTS[variant], folder)


def extra_model_path(name: str, folder: Path | None = None) -> Path:
    """The converted model ``name`` of :data:`EXTRA_MODELS` (hands: the default hand model, face); DetectError
    naming the command that prepares it when missing."""
    return hand_landmark_path(folder=folder) if name == HANDS else _prepared(name, EXTRA_MODELS[name][0], folder)


def _prepared(name: str, model: ModelFile, folder: Path | None) -> Path:
    """``model``'s converted file, which ``models fetch name`` prepares; DetectError naming that command when
    missing."""
    path = onnx_path(model, folder)
    if not path.is_file():
        raise DetectError(f"the {name} landmark model is not prepared on this machine ({path} missing): run "
                          f"`{FETCH_COMMAND} {name}` once, with access to the package index (it downloads the "
                          f"pinned MediaPipe package and converts the model; nothing is fetched at run time)")
    return path


def sha256_of(path: Path) -> str:
    """The sha256 of a file, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _download_pypi(package: Package, into: Path) -> Path:
    """The pinned wheel, fetched by pip from the configured index (any host platform)."""
    command = [sys.executable, "-m", "pip", "download", f"{package.name}=={package.version}", "--no-deps",
               "--only-binary=:all:", "--platform", "manylinux_2_28_x86_64", "--python-version", "3.11",
               "--implementation", "cp", "--abi", "cp311", "--quiet", "-d", str(into)]
    _run(command, package)
    return into / package.file_name


def _download_npm(package: Package, into: Path) -> Path:
    """The pinned npm tarball: ``npm pack`` (the configured registry) or, without npm, the public
    registry's tarball address."""
    if shutil.which("npm"):
        _run(["npm", "pack", f"{package.name}@{package.version}", "--silent", "--pack-destination", str(into)],
             package)
    else:
        import urllib.request
        registry = os.environ.get("NPM_CONFIG_REGISTRY", "https://registry.npmjs.org").rstrip("/")
        url = f"{registry}/{package.name}/-/{package.name.split('/')[-1]}-{package.version}.tgz"
        try:
            urllib.request.urlretrieve(url, into / package.file_name)
        except OSError as exc:
            raise DetectError(f"could not download {url} ({exc}): is the npm registry reachable?") from None
    return into / package.file_name


def _run(command: list[str], package: Package) -> None:
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=1800)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise DetectError(f"could not fetch {package.name}=={package.version}: {exc}") from None
    if done.returncode != 0:
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no message"]
        raise DetectError(f"could not fetch {package.name}=={package.version} from the {package.index} index "
                          f"({tail[0]}): is the package index reachable?")


_DOWNLOADERS: dict[str, Callable[[Package, Path], Path]] = {"pypi": _download_pypi, "npm": _download_npm}


def _extract(archive: Path, model: ModelFile, into: Path) -> Path:
    """``model``'s member of the wheel (zip) or tarball, written into ``into`` and checked against its sha256."""
    target = tflite_path(model, into)
    if archive.suffix == ".whl":
        with zipfile.ZipFile(archive) as wheel:
            target.write_bytes(wheel.read(model.member))
    else:
        with tarfile.open(archive) as tar:
            member = tar.extractfile(model.member)
            if member is None:
                raise DetectError(f"{archive.name}: no file {model.member}")
            target.write_bytes(member.read())
    if sha256_of(target) != model.sha256:
        raise DetectError(f"{model.member} in {archive.name}: sha256 {sha256_of(target)} is not the pinned "
                          f"{model.sha256}")
    return target


def fetch_models(variants: tuple[str, ...] = (DEFAULT_BLAZEPOSE,), folder: Path | None = None,
                 say: Callable[[str], None] = print, extras: tuple[str, ...] = ()) -> list[Path]:
    """Downloads, checks and converts the person detector, the ``variants`` landmark models and the
    ``extras`` (names of :data:`EXTRA_MODELS`: hands, face) into ``folder`` (default :func:`models_dir`);
    files already there with their model card are kept. Returns the ONNX paths; DetectError for a download
    or a checksum that fails."""
    from mocapdb.detect.tflite_onnx import convert_tflite

    folder = folder or models_dir()
    folder.mkdir(parents=True, exist_ok=True)
    wanted = [DETECTOR] + [LANDMARKS[v] for v in variants] + [m for e in extras for m in EXTRA_MODELS[e]]
    todo = [m for m in wanted if not _card_matches(m, folder)]
    with tempfile.TemporaryDirectory(prefix="mocapdb-models-") as scratch:
        archives: dict[Package, Path] = {}
        for model in todo:
            if model.package not in archives:
                say(f"fetching {model.package.name} {model.package.version} ({model.package.index})")
                archives[model.package] = _checked_download(model.package, Path(scratch))
            tflite = _extract(archives[model.package], model, folder)
            say(f"converting {Path(model.member).name} → {onnx_path(model, folder)}")
            partial = onnx_path(model, folder).with_suffix(".onnx.partial")
            convert_tflite(tflite, partial, doc=_card_text(model))
            os.replace(partial, onnx_path(model, folder))
            write_atomic(_card_path(model, folder), _card_text(model))
    return [onnx_path(m, folder) for m in wanted]


def _checked_download(package: Package, into: Path) -> Path:
    archive = _DOWNLOADERS[package.index](package, into)
    if not archive.is_file():
        raise DetectError(f"{package.name}=={package.version}: the index gave no {package.file_name}")
    if sha256_of(archive) != package.sha256:
        raise DetectError(f"{archive.name}: sha256 {sha256_of(archive)} is not the pinned {package.sha256}")
    return archive


def _card_path(model: ModelFile, folder: Path) -> Path:
    return folder / f"{model.stem}.json"


def _card_text(model: ModelFile) -> str:
    """The model card: where the file comes from, its checksum and licence, who converted it."""
    return json.dumps({
        "model": model.stem, "source_package": f"{model.package.index}:{model.package.name}=={model.package.version}",
        "source_file": model.member, "source_sha256": model.sha256, "license": model.package.license,
        "authors": _AUTHORS.get(model.stem, BLAZEPOSE_AUTHORS),
        "converted_by": "mocapdb.detect.tflite_onnx"}, indent=1)


def _card_matches(model: ModelFile, folder: Path) -> bool:
    try:
        files = onnx_path(model, folder).is_file() and tflite_path(model, folder).is_file()
        return files and _card_path(model, folder).read_text() == _card_text(model)
    except OSError:
        return False
