"""Every option of every command has a declared domain, and hostile values are refused cleanly.

The test walks the real parser (``mocapdb.cli.main.parser``): an option added tomorrow is covered
the day it is added, and one added without a domain fails :func:`test_every_option_has_a_declared_type`.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
from pathlib import Path

import pytest

from mocapdb.cli.main import main, parser
from mocapdb.cli.paths import PathArg, TextArg
from mocapdb.core.domains import Domain, ImageSizeArg, NumberListArg, PerTrackArg

from .conftest import SAMPLE_BVH, SAMPLE_KEYPOINTS

HOSTILE_NUMBERS = ("0", "-1", "nan", "inf", "-inf", "1e308", "1e20", "100000000000000000000", "1" + "0" * 400,
                   "abc", "", "0x10")
HOSTILE_SIZES = ("0x0", "-1x100", "1e20x2000", "100000000000000000000x2000", "nanxnan", "big", "1920x", "x")
HOSTILE_LISTS = ("nan", "inf,1", "-1", "0,0", "", "1e308", ",", "1," * 100)
HOSTILE_PER_TRACK = ("nan", "=1.7", "-1=1.7", "x=1.7", "1.5=1.7", "1e20=1.7", "2=", "2=abc", "2=inf", "2=1e308",
                     "2==1.7", "")
FLAGS = (argparse._HelpAction, argparse._VersionAction, argparse._StoreTrueAction, argparse._CountAction,
         argparse._StoreConstAction, argparse._SubParsersAction)

ROOT = Path(__file__).resolve().parents[1]


def _commands() -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _options(kind) -> list[tuple[str, argparse.Action]]:
    return [(name, a) for name, p in _commands().items() for a in p._actions
            if a.option_strings and isinstance(a.type, kind)]


def _name(action: argparse.Action) -> str:
    return action.option_strings[-1]


def _run(command: str, action: argparse.Action, value: str, capsys) -> tuple[int, str]:
    if action.nargs == "?":  # an optional value (live --view [PORT]): a dash-led one after a space is the next option
        code = main([command, f"{_name(action)}={value}"])
    else:
        nargs = action.nargs if isinstance(action.nargs, int) else 1
        code = main([command, *(_name(action), *[value] * nargs)])
    return code, capsys.readouterr().err


def test_every_option_has_a_declared_type():
    """A flag, a choice, a number's domain, an image size, a number list, a path or free text:
    anything else (``type=float``, an untyped string) is an option nobody checks."""
    declared = (Domain, ImageSizeArg, NumberListArg, PathArg, TextArg, PerTrackArg)
    unchecked = [f"{name} {a.option_strings or a.dest}" for name, p in _commands().items() for a in p._actions
                 if not isinstance(a, FLAGS) and a.choices is None and not isinstance(a.type, declared)]
    assert unchecked == []
    numbers = _options((Domain, ImageSizeArg, NumberListArg))
    paths = [(n, a) for n, p in _commands().items() for a in p._actions if isinstance(a.type, PathArg)]
    print(f"{len(numbers)} numeric and {len(paths)} path options of {len(_commands())} commands checked")
    assert len(numbers) >= 60 and len(paths) >= 25


@pytest.mark.parametrize("command, action", _options(Domain), ids=lambda v: getattr(v, "dest", v))
def test_hostile_numbers_are_refused_naming_the_option(command, action, capsys):
    for text in HOSTILE_NUMBERS:
        code, err = _run(command, action, text, capsys)
        try:
            accepted = action.type.accepts(int(text, 10) if action.type.integer else float(text))
        except ValueError:
            accepted = False
        if accepted:  # in the domain (0 for a limit): not refused for this option
            assert f"argument {_name(action)}:" not in err, (command, text, err)
        else:
            assert code == 2 and err.count("\n") == 1 and f"argument {_name(action)}:" in err, (command, text, err)
        assert "Traceback" not in err


@pytest.mark.parametrize("command, action", _options((ImageSizeArg, NumberListArg)),
                         ids=lambda v: getattr(v, "dest", v))
def test_hostile_sizes_and_lists_are_refused_naming_the_option(command, action, capsys):
    for text in HOSTILE_SIZES if isinstance(action.type, ImageSizeArg) else HOSTILE_LISTS:
        code, err = _run(command, action, text, capsys)
        assert code == 2 and err.count("\n") == 1 and f"argument {_name(action)}:" in err, (command, text, err)


@pytest.mark.parametrize("command, action", _options(PerTrackArg), ids=lambda v: getattr(v, "dest", v))
def test_hostile_per_track_values_are_refused_naming_the_option(command, action, capsys):
    for text in HOSTILE_PER_TRACK:
        code, err = _run(command, action, text, capsys)
        assert code == 2 and err.count("\n") == 1 and f"argument {_name(action)}:" in err, (command, text, err)
    assert action.type("1.62") == (None, 1.62) and action.type("2=1.1") == (2, 1.1)


def test_domains_hold_the_documented_values():
    from mocapdb.core import domains as D

    assert D.FPS_HZ("60") == 60.0 and D.LAG_FRAMES("0") == 0 and D.IMAGE_SIZE("1080X1920") == (1080, 1920)
    assert D.WINDOW_WEIGHTS("0.4, 0.3,0.2,0.1") == (0.4, 0.3, 0.2, 0.1)
    for domain, bad in [(D.FPS_HZ, "0"), (D.CUTOFF_HZ, "0"), (D.MAX_CLIENTS, "0"), (D.PER_CLUSTER, "1.5"),
                        (D.FOCAL_PX, "1e308"), (D.SEED, str(2**32))]:
        with pytest.raises(argparse.ArgumentTypeError, match="must be"):
            domain(bad)
    assert D.MAX_TRACKS.describe() == "a number of tracks, from 0 to 10,000; 0: no limit"


def test_the_api_refuses_what_the_cli_refuses():
    """One definition: the config classes check the same domains as the options."""
    from mocapdb.core.domains import DomainError
    from mocapdb.runtime.engine_config import EngineConfig, TrackLimits
    from mocapdb.runtime.filters import OneEuroParams
    from mocapdb.runtime.stream.session_options import SessionOptions
    from mocapdb.runtime.stream.transport import NetworkLimits
    from mocapdb.runtime.take_params import TakeParams

    for make in [lambda: EngineConfig(per_cluster=0), lambda: EngineConfig(fps=float("nan")),
                 lambda: EngineConfig(focal_px=1e308), lambda: EngineConfig(window_weights=(0.0, 0.0)),
                 lambda: EngineConfig(image_size=(10**20, 2000)), lambda: EngineConfig(n_clusters=10**20),
                 lambda: TrackLimits(max_tracks=-1), lambda: OneEuroParams(beta=float("inf")),
                 lambda: SessionOptions(bvh_part_min=float("inf")), lambda: NetworkLimits(client_timeout_s=-1),
                 lambda: TakeParams(smoothing_hz=float("nan"))]:
        with pytest.raises(DomainError, match="must"):
            make()


# --- paths -----------------------------------------------------------------------------------

@pytest.fixture
def special_paths(tmp_path):
    fifo = tmp_path / "pipe.bvh"
    os.mkfifo(fifo)
    zero = tmp_path / "zero.bvh"
    zero.symlink_to("/dev/zero")
    loop = tmp_path / "loop.json"
    loop.symlink_to(loop)
    (tmp_path / "a_file.txt").write_text("x")
    (tmp_path / "a_folder").mkdir()
    return {"missing": tmp_path / "missing", "fifo": fifo, "device": zero, "loop": loop,
            "file": tmp_path / "a_file.txt", "folder": tmp_path / "a_folder"}


def test_path_options_refuse_missing_special_and_wrong_kind_paths(special_paths, capsys):
    checked = 0
    for command, command_parser, action in [(n, p, a) for n, p in _commands().items() for a in p._actions
                                            if isinstance(a.type, PathArg)]:
        kind = action.type
        bad = ["fifo", "device"] + (["missing", "loop"] if kind.role == "input" else [])
        bad += {"file": ["folder"], "dir": ["file"]}.get(kind.kind, []) if kind.role == "input" else []
        for case in bad:
            argv = [command, *_path_args(command_parser, action, str(special_paths[case]),
                                         str(special_paths["folder"]))]
            code = main(argv)
            err = capsys.readouterr().err
            assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, (argv, err)
            assert f"argument {_name(action) if action.option_strings else action.dest}:" in err, (argv, err)
            checked += 1
    assert checked > 60


def _path_args(command: argparse.ArgumentParser, action: argparse.Action, path: str, folder: str) -> list[str]:
    """``path`` given to ``action`` alone: an option with its values, or a positional after valid
    folders for the positionals before it."""
    if action.option_strings:
        return [_name(action), *[path] * (action.nargs if isinstance(action.nargs, int) else 1)]
    before = [a for a in command._actions if not a.option_strings].index(action)
    return [*[folder] * before, path]


def test_text_options_are_bounded(capsys):
    for command, action in _options(TextArg):
        code, err = _run(command, action, "x" * 5000, capsys)
        assert code == 2 and f"argument {_name(action)}:" in err, (command, err)


# --- outputs apart from inputs ---------------------------------------------------------------

def _digest(path: Path) -> str:
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(str(f.relative_to(path)).encode() + f.read_bytes())
    return h.hexdigest()


def test_an_output_over_an_input_is_refused_and_the_input_kept(tmp_path, small_db_path, capsys):
    keypoints = tmp_path / "take" / "keypoints"
    shutil.copytree(SAMPLE_KEYPOINTS, keypoints)
    bvh_dir = tmp_path / "bvh"
    shutil.copytree(SAMPLE_BVH, bvh_dir)
    before = _digest(tmp_path)
    db = str(small_db_path)
    cases = [
        (["reconstruct", str(keypoints), "--db", db, "--out", str(keypoints)], "is the input"),
        (["reconstruct", str(keypoints), "--db", db, "--out", str(keypoints.parent)], "holds the input"),
        (["reconstruct", str(keypoints), "--db", db, "--out", str(keypoints / "out")], "lies inside the input"),
        (["reconstruct", str(keypoints), "--db", db, "--out", str(Path(db) / "out")], "lies inside the input --db"),
        (["stereo", str(keypoints), str(keypoints), "--focal", "1000", "--image-size", "1920x1080",
          "--out", str(keypoints)], "is the input"),
        (["build", str(bvh_dir), "--out", str(bvh_dir / "db")], "lies inside the input"),
        (["live", "--source", str(keypoints), "--db", db, "--sink", str(keypoints / "out.jsonl")], "lies inside"),
        (["render", db, "--out", str(Path(db) / "frames")], "lies inside the input"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err and "choose an output apart" in err, (argv, err)
    assert _digest(tmp_path) == before


def test_an_output_folder_beside_its_input_is_fine(tmp_path, small_db_path, capsys):
    """Adding files next to an input (live's --bvh-dir beside the video) is not writing over it."""
    from mocapdb.cli.main import command_parser
    from mocapdb.cli.paths import check_outputs_apart

    video = tmp_path / "take.mp4"
    video.write_bytes(b"\0")
    args = parser().parse_args(["live", "--source", str(video), "--db", str(small_db_path),
                                "--bvh-dir", str(tmp_path)])
    check_outputs_apart(command_parser("live"), args)


STATED_DEFAULT = re.compile(r"\bdefault:? (-?\d[\d.,]*)")


def _stated_defaults() -> list[tuple[str, argparse.Action, str]]:
    """(command, action, number) for every number a help text states as the default."""
    out = []
    for name, p in _commands().items():
        for a in p._actions:
            if a.help and a.help is not argparse.SUPPRESS:
                text = a.help % {"default": a.default, "prog": name}
                out += [(name, a, m.rstrip(".,")) for m in STATED_DEFAULT.findall(text)]
    return out


def test_help_texts_state_the_declared_defaults():
    """A default is declared once (a domain's or a named constant) and the help derives it: a help
    whose parser holds a default says it through %(default)s, and the number it shows is that
    default; no help text types a default's number by hand (checked in the source below)."""
    wrong = []
    for name, a, number in _stated_defaults():
        if a.default is None:
            continue   # the default lives elsewhere (a take.json, a rule): derived in the source, below
        declared = ",".join(map(str, a.default)) if isinstance(a.default, (list, tuple)) else a.default
        if not _same_number(number, declared):
            wrong.append(f"{name} {a.option_strings or a.dest}: states default {number}, declares {declared!r}")
        elif "%(default)s" not in a.help:
            wrong.append(f"{name} {a.option_strings or a.dest}: states its default by hand, not %(default)s")
    assert not wrong, "\n".join(wrong)


def test_no_help_text_types_a_default_by_hand():
    """In the parsers' source, no string literal says "default" followed by a number: the number
    comes from %(default)s or from the constant that declares it (an f-string's field)."""
    import ast

    typed = []
    for path in sorted((ROOT / "mocapdb" / "cli").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and STATED_DEFAULT.search(node.value):
                typed.append(f"{path.name}:{node.lineno}: {node.value.strip()[:80]}")
    assert not typed, "\n".join(typed)


def _same_number(text: str, value: object) -> bool:
    try:
        return all(float(t) == float(v) for t, v in zip(text.split(","), str(value).split(","), strict=True))
    except ValueError:
        return False
