"""The generated reference pages (docs/gen_reference.py, run by the MkDocs hook at every build)."""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def generator():
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "docs" / "gen_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_console_script_exposes_the_parser_its_main_uses(generator):
    for name, target in generator.console_scripts().items():
        parser = generator.script_parser(target)
        assert isinstance(parser, argparse.ArgumentParser), name
        assert parser.prog == name, f"{target}: build_parser() is for {parser.prog!r}, not {name!r}"


def test_the_cli_page_holds_every_command_help(generator):
    page = generator.cli_page()
    for name in generator.console_scripts():
        assert f"\n## {name}\n" in page
        assert f"usage: {name}" in page


def test_the_schema_page_has_every_table_and_key(generator):
    from interfaces.scenario import Scenario, VehicleConfig

    page = generator.schema_page()
    for name, field in Scenario.model_fields.items():
        assert f"| `{name}` |" in page
    for table in ("[estimator]", "[guidance]", "[target.circle]", "[[swarm.pursuers]]", "[health]", "[safety]"):
        assert f"## `{table}`" in page, table
    for name in VehicleConfig.model_fields:
        assert f"| `{name}` |" in page
    assert "| `rate_hz` | float (> 0, <= 10000) | 50 |" in page  # [estimator] rate_hz: type, bounds and default
    # A vector's component bounds and an optional key's bounds are shown too.
    assert "| `initial_position` | [float, float, float] (each >= -10000, <= 10000) | [0, 0, 0] |" in page
    assert "| `inertia` | [float, float, float] (each >= 1e-05, <= 10) |" in page
    assert "| `range_noise_std` | float (>= 0) or none | none |" in page


def test_the_equation_page_lists_the_method(generator):
    page = generator.equations_page()
    for row in ("| eq. (6) | `companion.core.estimators.UPLKF.correct` |",
                "| eq. (14) | `companion.core.guidance.HelicalNavigationGuidance.acceleration` |",
                "| eq. (21)-(22) | `companion.core.attitude.attitude_setpoint` |"):
        assert row in page, row


def test_the_zenoh_page_names_every_key_schema_and_refusal_of_the_link_schema_and_no_other():
    """docs/reference/zenoh.md is written by hand: it must name every schema version and refusal reason
    interfaces.link_schema declares (and no reason it does not), and every key expression its key functions build."""
    import re

    from interfaces import link_schema

    page = (Path(__file__).resolve().parent.parent / "docs" / "reference" / "zenoh.md").read_text()
    schemas = {value for name, value in vars(link_schema).items() if name.endswith(("_SCHEMA", "_SCHEMA_V1"))}
    for schema in schemas:
        name, version = schema.split("/")
        assert f"`{schema}`" in page or re.search(rf"`{re.escape(name)}` \| {version} \|", page), schema
    refusals = set(re.findall(r"^\| `([a-z0-9_]+)` \| ", page.split("## Refusals")[1], flags=re.M))
    assert refusals == set(link_schema.REASONS)
    keys = {link_schema.CLOCK_KEY, link_schema.target_fix_key("S"), link_schema.companion_state_key("I"),
            link_schema.companion_command_key("I"), link_schema.target_command_key("S"),
            link_schema.pursuer_share_key(7)}
    shown = {key.replace("<sender>", "S").replace("<id>", "I").replace("<pursuer>", "7")
             for key in re.findall(r"^\| `(bof/[^`]+)` \|", page, flags=re.M)}
    assert shown == keys


def test_the_link_faults_page_describes_every_fault_key_and_corruption_kind():
    """docs/reference/link-faults.md is written by hand: every key of [faults] and [faults.burst] appears on it,
    every corruption kind with the refusal reason sitl_plant's CORRUPTION_REASONS gives it, and every random
    stream."""
    import re

    from interfaces.scenario.faults import BurstLossConfig, FaultsConfig
    from sitl_plant.world.link_faults import CORRUPTION_REASONS, STREAMS

    page = (Path(__file__).resolve().parent.parent / "docs" / "reference" / "link-faults.md").read_text()
    keys = (set(FaultsConfig.model_fields) | set(BurstLossConfig.model_fields)) - {"burst", "mavlink"}
    assert {key for key in keys if f"`{key}`" not in page} == set()
    rows = dict(re.findall(r"^ *\| `([a-z_0-9]+)` \| `([a-z_0-9]+)` \|", page, flags=re.M))
    assert rows == CORRUPTION_REASONS
    streams = page.split("one stream per fault kind (")[1].split(")")[0]
    assert [name.strip() for name in streams.split(",")] == list(STREAMS)
