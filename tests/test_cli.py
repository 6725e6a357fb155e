"""The ``webline`` dispatcher: help, unknown commands, and no bare tracebacks."""
import sys

from webline import cli


def test_help_lists_every_command(capsys):
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in cli.COMMANDS:
        assert name in out


def test_unknown_command_exits_2(capsys):
    assert cli.main(["no-such-command"]) == 2
    assert "unknown command" in capsys.readouterr().err


def test_internal_error_is_a_message_not_a_traceback(monkeypatch, capsys):
    monkeypatch.delenv("WEBLINE_DEBUG", raising=False)
    module = type(sys)("webline_test_boom")
    module.main = lambda argv: 1 / 0
    monkeypatch.setitem(sys.modules, "webline_test_boom", module)
    monkeypatch.setitem(cli.COMMANDS, "boom", ("webline_test_boom", "raises"))
    assert cli.main(["boom"]) == 1
    err = capsys.readouterr().err
    assert "internal error: ZeroDivisionError" in err and "Traceback" not in err


def test_every_command_has_help(capsys):
    for name in cli.COMMANDS:
        try:
            code = cli.main([name, "--help"])
        except SystemExit as exc:  # argparse exits 0 after printing help
            code = exc.code
        assert code == 0, name
        assert "usage" in capsys.readouterr().out.lower(), name
