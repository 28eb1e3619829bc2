"""docs/semantics.md §2: every SGCConfig field is static, a program value or host-only, and has the
command-line option, as the table says."""

import argparse
import dataclasses
import re
from pathlib import Path

import pytest

from sgc_jax.cli import build_parser
from sgc_jax.config import HOST_FIELDS, STATIC_FIELDS, VALUE_FIELDS, SGCConfig

SEMANTICS = Path(__file__).resolve().parents[1] / "docs" / "semantics.md"


def test_every_field_has_exactly_one_role():
    roles = STATIC_FIELDS + VALUE_FIELDS + HOST_FIELDS
    assert sorted(roles) == sorted(f.name for f in dataclasses.fields(SGCConfig)) and len(set(roles)) == len(roles)


def test_the_documented_static_fields_are_the_static_fields():
    table = SEMANTICS.read_text().split("## 2. Configuration")[1].split("\n## ")[0]
    rows = re.findall(r"^\| `(\w+)` \|.*\|$", table, flags=re.M)
    marked = [name for name in rows if re.search(rf"^\| `{name}` \|.*\(\*static\*\) \|$", table, flags=re.M)]
    assert sorted(rows) == sorted(f.name for f in dataclasses.fields(SGCConfig))
    assert sorted(marked) == sorted(STATIC_FIELDS)


def subcommand_parser(command: str) -> argparse.ArgumentParser:
    parser = build_parser()
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]


def documented_flags() -> dict[str, set[str]]:
    """Field -> the options in the CLI column of the §2 table."""
    table = SEMANTICS.read_text().split("## 2. Configuration")[1].split("\n## ")[0]
    rows = re.findall(r"^\| `(\w+)` \|[^|]*\|([^|]*)\|", table, flags=re.M)
    return {name: set(re.findall(r"`(--[\w-]+)`", cli)) for name, cli in rows}


@pytest.mark.parametrize("command", ["score", "perturb"])
def test_every_field_is_an_option_as_documented(command):
    """The §2 CLI column names each field's options, and the parser (built from config.py) has them."""
    names = {f.name for f in dataclasses.fields(SGCConfig)}
    parsed = {a.dest: set(a.option_strings) for a in subcommand_parser(command)._actions if a.dest in names}
    assert parsed == documented_flags()


def test_every_field_has_help_text():
    assert all(f.metadata.get("help") for f in dataclasses.fields(SGCConfig))


def test_a_negative_layer_count_rule_is_refused():
    with pytest.raises(ValueError, match="tracks_per_layer"):
        SGCConfig(tracks_per_layer=-1)
