"""A command line builds the arguments of its own command only (``_parser(name)``): that command's
parser is the whole parser's, the others are listed as before."""
import argparse
import contextlib
import io

import pytest

from orchestrator.cli import _parser, command_list


def _commands(parser):
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices


def _shape(cmd: argparse.ArgumentParser):
    """What parsing with ``cmd`` depends on: its actions and defaults, and its help text."""
    actions = [(type(a).__name__, tuple(a.option_strings), a.dest, repr(a.default), a.type, a.nargs,
                None if a.choices is None else tuple(a.choices), a.required, a.const, a.metavar, a.help)
               for a in cmd._actions]
    return actions, cmd._defaults, cmd.format_help(), cmd.format_usage()


NAMES = list(_commands(_parser()))


@pytest.mark.parametrize("name", NAMES)
def test_a_command_s_own_parser_is_the_whole_parser_s(name):
    whole, one = _parser(), _parser(name)
    assert list(_commands(one)) == NAMES and command_list(one) == command_list(whole)
    assert _shape(_commands(one)[name]) == _shape(_commands(whole)[name])
    others = [n for n in NAMES if n != name]
    assert all(len(_commands(one)[n]._actions) == 1 for n in others)       # -h only: not made
    assert one.format_help() == whole.format_help()


@pytest.mark.parametrize("argv", [["run", "reactor", "--route", "monolithic", "-o", "x.h5", "--pga", "0.3"],
                                  ["run", "--bogus"], ["runn"], ["--help"], ["scene", "--help"]])
def test_a_command_line_parses_the_same_with_its_own_parser(argv):
    def parsed(parser):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                return vars(parser.parse_args(argv)), out.getvalue(), err.getvalue()
            except SystemExit as exc:
                return exc.code, out.getvalue(), err.getvalue()
    assert parsed(_parser(argv[0] if not argv[0].startswith("-") else None)) == parsed(_parser())
