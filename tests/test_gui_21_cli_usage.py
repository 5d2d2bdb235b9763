"""A mistyped or unknown subcommand (issue 21 item 6): ``impress compar --help`` printed
``impress gui``'s help and exited 0. Now it is a usage error (E-USAGE, exit status 2) that
names the closest command, whether or not ``--help`` follows, and opens no window; a real
command's ``--help`` is still its own."""

from __future__ import annotations

import pytest

from impress_gui import cli


@pytest.mark.parametrize(("argv", "suggested"), [
    (["compar", "--help"], "compare"),
    (["proces", "scan.mp4"], "process"),
    (["calibrat", "-h"], "calibrate"),
    (["simulat"], "simulate"),
])
def test_a_mistyped_command_is_an_error_with_a_suggestion(argv, suggested, capsys,
                                                          monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # no file of that name here
    opened = []
    monkeypatch.setattr(cli, "run_command", lambda *a: opened.append(a) or 0)
    code = cli.main(argv)
    out, err = capsys.readouterr()
    assert code == 2 and opened == []
    assert "[E-USAGE]" in err and f"Did you mean 'impress {suggested}'?" in err, err
    assert "usage: impress gui" not in out + err


def test_an_unknown_word_lists_the_commands(capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["zebra", "--help"]) == 2
    err = capsys.readouterr().err
    assert "'zebra' is not a command" in err and "Did you mean" not in err
    for name in ("simulate", "calibrate", "process", "compare", "gui"):
        assert name in err


def test_a_real_commands_help_is_its_own(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["compare", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: impress compare")
