"""The `mocapdb` command: every subcommand answers --help; unknown input exits 2 without a traceback."""
import argparse

import pytest

from mocapdb.cli.main import main, parser


def _subcommands() -> list[str]:
    actions = [a for a in parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return sorted(actions[0].choices)


def test_every_product_command_is_there():
    assert {"build", "inspect", "reconstruct", "live", "eval", "detect", "stereo"} <= set(_subcommands())


@pytest.mark.parametrize("command", _subcommands())
def test_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: mocapdb {command}")


def test_stereo_without_intrinsics_is_a_clear_error(tmp_path, capsys):
    assert main(["stereo", str(tmp_path), str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "--calibration" in err and "Traceback" not in err


def test_eval_reports_are_strict_json():
    import json

    from mocapdb.cli.evaluate import _report_json

    text = _report_json({"mpjpe_cm": float("nan"), "rows": [1.5, float("inf")], "nested": {"x": -float("inf")}})
    assert json.loads(text) == {"mpjpe_cm": None, "rows": [1.5, None], "nested": {"x": None}}
    assert "NaN" not in text and "Infinity" not in text
