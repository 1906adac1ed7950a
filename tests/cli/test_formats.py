"""pgdcli.cli.formats: each command's --format choices, default, help and writers from one registry."""

from __future__ import annotations

import io

import click
import pytest

from pgdcli.cli import query as lean_query
from pgdcli.cli.formats import FIT, INFO, QUERY, SENSITIVITY, SOLVE, VERIFY, Formats
from pgdcli.cli.main import cli

REGISTRIES = {"query": QUERY, "fit": FIT, "info": INFO, "verify": VERIFY, "solve": SOLVE, "sensitivity": SENSITIVITY}


@pytest.mark.parametrize("command", sorted(REGISTRIES))
def test_the_format_option_is_the_registry(command):
    formats = REGISTRIES[command]
    (option,) = [p for p in cli.commands[command].params if p.name == "fmt"]
    assert isinstance(option.type, click.Choice)
    assert tuple(option.type.choices) == formats.names and option.default == formats.default
    assert option.help == formats.help() and formats.default in formats.names
    for name in formats.names:
        assert callable(formats.writer(name)) or hasattr(formats.writer(name), "chunk")


def test_the_lean_query_parser_accepts_the_registry_and_nothing_else():
    for name in QUERY.names:
        assert lean_query._split(["cb.h5", "--format", name, "--t", "1"])[1] == name
    assert lean_query._split(["cb.h5", "--format", "xml", "--t", "1"]) is None  # click reports it


def test_an_unknown_format_is_an_error_not_another_format():
    with pytest.raises(ValueError, match=r"pgd query: no output format 'xml'; expected one of plain, csv, json"):
        QUERY.writer("xml")


def test_a_registry_keeps_the_order_and_refuses_a_name_twice():
    formats = Formats("demo", "b")
    formats.register("b", "bee")(print)
    formats.register("a", "ay")(repr)
    assert formats.names == ("b", "a") and formats.writer("a") is repr
    assert formats.help() == "b: bee; a: ay."
    with pytest.raises(ValueError, match="pgd demo: output format 'a' registered twice"):
        formats.register("a", "again")(str)


@pytest.mark.parametrize("name,expected", [
    ("plain", "1.5 -2.0\n0.25 3.0\n"),
    ("csv", "t,k,u,w\n0.0,1.0,1.5,-2.0\n1.0,2.0,0.25,3.0\n"),
    ("json", '[{"t": 0.0, "k": 1.0, "u": 1.5, "w": -2.0}, {"t": 1.0, "k": 2.0, "u": 0.25, "w": 3.0}]\n'),
])
def test_each_query_format_writes_its_rows(name, expected):
    writer = QUERY.writer(name)
    points, rows = [(0.0, 1.0), (1.0, 2.0)], [[1.5, -2.0], [0.25, 3.0]]
    text = writer.chunk(["t", "k"], ["u", "w"], points, rows, True) + writer.closing(["t", "k"], ["u", "w"], True)
    assert text == expected
    empty = writer.closing(["t", "k"], ["u", "w"], False)
    assert empty == {"plain": "", "csv": "t,k,u,w\n", "json": "[]\n"}[name]


def test_each_fit_format_writes():
    class Result:
        estimate, stderr = {"k": 2.0}, {"k": 0.125}
        fitted, data = {"t": [0.0, 1.0], "u": [1.0, 0.5]}, {"u": [1.0, 0.625]}

        def to_dict(self):
            return {"estimate": self.estimate}

    outputs = {}
    for name in FIT.names:
        out = io.StringIO()
        FIT.writer(name)(out, Result())
        outputs[name] = out.getvalue()
    assert outputs == {"plain": "k 2.0 0.125\n", "csv": "t,u,u_data\n0.0,1.0,1.0\n1.0,0.5,0.625\n",
                       "json": '{\n  "estimate": {\n    "k": 2.0\n  }\n}\n'}
