"""hsa_core.cli: the shared argument types refuse what the CLIs' docs refuse, and a refusal is
one line on stderr with exit status 2."""

from __future__ import annotations

import argparse

import pytest

from hsa_core import cli


@pytest.mark.parametrize(
    ("convert", "text", "value"),
    [
        (cli.positive, "2.5", 2.5),
        (cli.positive, "1e-9", 1e-9),
        (cli.positive_int, "1", 1),
        (cli.positive_int, "40", 40),
        (cli.non_negative, "0", 0.0),
        (cli.non_negative, "0.25", 0.25),
    ],
)
def test_accepted_values(convert, text: str, value: float) -> None:
    assert convert(text) == value and type(convert(text)) is type(value)


@pytest.mark.parametrize(
    ("convert", "text", "message"),
    [
        (cli.positive, "0", "must be a finite number > 0, got 0"),
        (cli.positive, "-1", "must be a finite number > 0, got -1"),
        (cli.positive, "inf", "must be a finite number > 0, got inf"),
        (cli.positive, "nan", "must be a finite number > 0, got nan"),
        (cli.positive_int, "0", "must be an integer >= 1, got 0"),
        (cli.positive_int, "-3", "must be an integer >= 1, got -3"),
        (cli.non_negative, "-0.1", "must be a finite number >= 0, got -0.1"),
        (cli.non_negative, "inf", "must be a finite number >= 0, got inf"),
        (cli.non_negative, "nan", "must be a finite number >= 0, got nan"),
    ],
)
def test_refused_values_name_the_rule(convert, text: str, message: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError) as error:
        convert(text)
    assert str(error.value) == message


@pytest.mark.parametrize(
    ("convert", "text"), [(cli.positive, "fast"), (cli.positive_int, "1.5"), (cli.non_negative, "")]
)
def test_non_numbers_are_value_errors(convert, text: str) -> None:
    """argparse turns a ValueError of a type into "invalid <type> value"."""
    with pytest.raises(ValueError):
        convert(text)


def _parser() -> cli.ArgumentParser:
    parser = cli.ArgumentParser(prog="hsa_x")
    parser.add_argument("--rate", type=cli.positive, default=40.0)
    parser.add_argument("--plants", type=cli.positive_int, default=8)
    return parser


def test_a_bad_argument_is_one_line_on_stderr_and_exit_2(capsys) -> None:
    with pytest.raises(SystemExit) as done:
        _parser().parse_args(["--rate", "0"])
    assert done.value.code == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err == "hsa_x: error: argument --rate: must be a finite number > 0, got 0 (see --help)\n"


def test_unknown_arguments_and_non_numbers_are_refused_the_same_way(capsys) -> None:
    not_an_int = "argument --plants: invalid positive_int value: 'many'"
    for args, message in (
        (["--speed", "1"], "unrecognized arguments: --speed 1"),
        (["--plants", "many"], not_an_int),
    ):
        with pytest.raises(SystemExit) as done:
            _parser().parse_args(args)
        assert done.value.code == 2
        assert capsys.readouterr().err == f"hsa_x: error: {message} (see --help)\n"


def test_good_arguments_parse() -> None:
    parsed = _parser().parse_args(["--rate", "100", "--plants", "3"])
    assert vars(parsed) == {"rate": 100.0, "plants": 3}
