"""The CLI turns the project's errors into one stderr line and exit code 2."""

import os
import subprocess
import sys

import pytest

from hw.errors import HardwareError
from mapping.errors import MappingError
from robchair import cli
from robchair.platform.errors import RobChairError
from sim.errors import SimError


@pytest.mark.parametrize(
    "exc_type", [MappingError, HardwareError, SimError, RobChairError, FileNotFoundError]
)
def test_project_error_becomes_one_line_and_exit_code_2(
    exc_type: type[Exception], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def failing(_args: object) -> int:
        raise exc_type("input.pcd: truncated data section")

    parser = cli.build_parser()
    real_parse = parser.parse_args

    def parse(argv: object = None) -> object:
        ns = real_parse(["bench"])
        ns.func = failing
        ns.command = "demo"
        return ns

    monkeypatch.setattr(parser, "parse_args", parse)
    monkeypatch.setattr(cli, "build_parser", lambda *_argv: parser)
    assert cli.main([]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines() == ["robchair demo: error: input.pcd: truncated data section"]


def test_unexpected_errors_are_not_swallowed(monkeypatch: pytest.MonkeyPatch) -> None:
    parser = cli.build_parser()
    real_parse = parser.parse_args

    def parse(argv: object = None) -> object:
        ns = real_parse(["bench"])
        ns.func = lambda _a: 1 // 0
        return ns

    monkeypatch.setattr(parser, "parse_args", parse)
    monkeypatch.setattr(cli, "build_parser", lambda *_argv: parser)
    with pytest.raises(ZeroDivisionError):
        cli.main([])


def test_every_command_module_registers_and_shows_help() -> None:
    parser = cli.build_parser()
    names = set(parser._subparsers._group_actions[0].choices)  # type: ignore[union-attr,arg-type]
    assert {"map", "pid", "sim", "run", "hw", "bench"} <= names
    out = subprocess.run(
        [sys.executable, "-m", "robchair.cli", "--help"], capture_output=True, text=True, check=True
    ).stdout
    for name in ("map", "pid", "sim", "run", "hw", "bench"):
        assert name in out


def test_open3d_imports_through_the_libusb_preload_in_a_fresh_interpreter() -> None:
    code = "from mapping._deps import import_open3d; o3d = import_open3d(); print(o3d.__version__)"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip()


def test_open3d_is_imported_without_dash_and_its_dash_names_still_reach_the_real_dash() -> None:
    """open3d's visualization takes dash's ``html``, ``dcc`` and ``Dash`` at import (about 0.4 s of CPU
    per process, for ``draw_plotly_server`` only): import_open3d leaves dash unimported, and those names
    are dash's own objects once used; ``import dash`` afterwards is the real package."""
    code = (
        "import sys; from mapping._deps import import_open3d; import_open3d(); "
        "print('dash' in sys.modules); "
        "dp = sys.modules['open3d.visualization.draw_plotly']; "
        "import dash; from dash import html; "
        "print(dp.html.Div is html.Div, type(dp.Dash('t')) is dash.Dash, dash.__file__ is not None)"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["False", "True", "True", "True"]


def test_a_listed_command_module_that_is_missing_is_an_error_not_a_silent_skip(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(cli, "COMMANDS", (*cli.COMMANDS, "robchair.commands.no_such_command"))
    with pytest.raises(ModuleNotFoundError, match=r"robchair\.commands\.no_such_command"):
        cli.build_parser()
    monkeypatch.setattr(cli, "BENCHES", (*cli.BENCHES, "robchair.commands.bench_nothing"))
    monkeypatch.setattr(cli, "COMMANDS", cli.COMMANDS[:-1])
    with pytest.raises(ModuleNotFoundError, match=r"robchair\.commands\.bench_nothing"):
        cli.build_parser()


def _choices(parser: object) -> dict[str, object]:
    return dict(parser._subparsers._group_actions[0].choices)  # type: ignore[attr-defined]


def test_each_listed_module_registers_the_command_its_name_says() -> None:
    """What a command line's one-module parser relies on: the name it looks for is the name registered."""
    parser = cli.build_parser()
    assert set(_choices(parser)) == {cli.command_name(m) for m in cli.COMMANDS} | {"bench"}
    assert set(_choices(_choices(parser)["bench"])) == {cli.command_name(m) for m in cli.BENCHES}


@pytest.mark.parametrize(
    ("argv", "commands", "benches"),
    [
        (["-v", "sim", "--duration", "1"], {"sim"}, None),
        (["bench", "map", "--help"], {"bench"}, {"map"}),
        (["bench"], {"bench"}, {cli.command_name(m) for m in cli.BENCHES}),
        (["--help", "sim"], {cli.command_name(m) for m in cli.COMMANDS} | {"bench"}, None),
        (["simm"], {cli.command_name(m) for m in cli.COMMANDS} | {"bench"}, None),
    ],
)
def test_a_command_line_gets_the_parser_of_the_command_it_names_with_the_same_help(
    argv: list[str], commands: set[str], benches: set[str] | None
) -> None:
    full = cli.build_parser()
    parser = cli.build_parser(argv)
    assert set(_choices(parser)) == commands
    for name, sub in _choices(parser).items():
        if name != "bench":  # the bench parser's own help lists the benchmarks it has
            assert sub.format_help() == _choices(full)[name].format_help()  # type: ignore[attr-defined]
    if benches is not None:
        got = _choices(_choices(parser)["bench"])
        assert set(got) == benches
        for name, sub in got.items():
            assert sub.format_help() == _choices(_choices(full)["bench"])[name].format_help()  # type: ignore[attr-defined]


def test_a_command_imports_no_other_commands_module() -> None:
    """`robchair sim` no longer imports the modules of map, pid, bench ... (~0.3 s of CPU each run); its
    own module takes the live view's options from robchair.commands.live."""
    code = (
        "import sys\nfrom robchair import cli\ncli.build_parser(['sim', '--list'])\n"
        "print(sorted(m for m in sys.modules if m.startswith('robchair.commands.')))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "['robchair.commands.live', 'robchair.commands.sim']"


_HUGE_PAGES = (
    "import os, sys; from robchair import cli; code = cli.main(sys.argv[1:]); import numpy; "
    "print(numpy._core.multiarray._get_madvise_hugepage(), os.environ['NUMPY_MADVISE_HUGEPAGE'], code)"
)


@pytest.mark.parametrize(("given", "expected"), [(None, "False 0 0"), ("1", "True 1 0")])
def test_a_command_runs_without_numpy_huge_pages_unless_the_environment_asks(
    given: str | None, expected: str
) -> None:
    """`robchair` turns numpy's transparent huge pages off (its module docstring says why) before numpy is
    imported, and its child processes inherit that; NUMPY_MADVISE_HUGEPAGE set by the caller is kept."""
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if given is not None:
        env["NUMPY_MADVISE_HUGEPAGE"] = given
    res = subprocess.run([sys.executable, "-c", _HUGE_PAGES, "sim", "--list"], env=env, capture_output=True,
                         text=True, timeout=120)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[-1] == expected


def test_this_suite_runs_numpy_as_a_command_does() -> None:
    """tests/conftest.py sets NUMPY_MADVISE_HUGEPAGE before numpy's import, for the workers and every
    process they start."""
    import importlib

    multiarray = importlib.import_module("numpy._core.multiarray")
    assert multiarray._get_madvise_hugepage() == (os.environ["NUMPY_MADVISE_HUGEPAGE"] != "0")
