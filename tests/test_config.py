"""docs/semantics.md §2: every SGCConfig field is static, a program value or host-only, as the table says."""

import dataclasses
import re
from pathlib import Path

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
