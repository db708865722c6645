"""interfaces.overrides: `section.key=value` parsed as TOML, merged into a model, re-validated by the schema."""

from __future__ import annotations

import math
import tomllib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from interfaces.overrides import apply_overrides, format_assignment, parse_assignment
from interfaces.scenario import ConfigError, FaultsConfig, load_scenario

KEYS = st.from_regex(r"[a-z][a-z0-9_]{0,8}(\.[a-z][a-z0-9_]{0,8}){0,2}", fullmatch=True)
SCALARS = (st.booleans() | st.integers(-2**63, 2**63 - 1) | st.floats(allow_nan=False)
           | st.text(st.characters(blacklist_categories=("Cs",)), max_size=20))
VALUES = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=3)
                      | st.dictionaries(st.from_regex(r"[a-z_]{1,6}", fullmatch=True), inner, max_size=3), max_leaves=8)


@given(KEYS, VALUES)
def test_a_formatted_assignment_parses_back_to_the_same_key_and_value(key, value):
    text = format_assignment(key, value)
    assert parse_assignment(text, "--x") == (key, value)
    # The literal is TOML as tomllib reads it in a file, not only as parse_assignment reads it.
    assert tomllib.loads(f"v = {text.partition('=')[2]}")["v"] == value


def test_infinities_and_nan_are_toml_floats():
    assert parse_assignment(format_assignment("a", math.inf), "--x") == ("a", math.inf)
    assert parse_assignment(format_assignment("a", -math.inf), "--x") == ("a", -math.inf)
    assert math.isnan(parse_assignment(format_assignment("a", math.nan), "--x")[1])


@pytest.mark.parametrize("text, message", [
    ("loss_probability", "--fault 'loss_probability': expected KEY=VALUE"),
    ("=3", "expected KEY=VALUE"),
    ("a..b=3", "expected KEY=VALUE"),
    ("law=hng", "--fault law: 'hng' is not a TOML value"),
])
def test_malformed_assignments_are_refused_naming_them(text, message):
    with pytest.raises(ConfigError, match="^--fault") as error:
        parse_assignment(text, "--fault")
    assert message in str(error.value)


def test_overrides_merge_into_nested_sections_and_keep_the_rest(scenario_path):
    scenario, _ = load_scenario(scenario_path("constant_velocity"))
    changed = apply_overrides(scenario, {"guidance.c_y": 0.0, "faults.burst.mean_burst_s": 2.0,
                                         "faults.burst.mean_gap_s": 8.0}, "--case")
    assert changed.guidance.c_y == 0.0 and changed.guidance.c_z == scenario.guidance.c_z
    assert (changed.faults.burst.mean_burst_s, changed.faults.burst.mean_gap_s) == (2.0, 8.0)
    assert scenario.faults.burst is None  # the original is untouched
    # A whole table replaces the table: what it does not name goes back to the schema's defaults.
    replaced = apply_overrides(changed, {"faults": {"loss_probability": 0.3}}, "--case")
    assert replaced.faults == FaultsConfig(loss_probability=0.3)


def test_pairs_apply_in_order():
    pairs = [("burst", {"mean_burst_s": 1.0, "mean_gap_s": 4.0}), ("burst.mean_burst_s", 2.0),
             ("burst", {"p_good_to_bad": 0.1, "p_bad_to_good": 0.5})]
    config = apply_overrides(FaultsConfig(), pairs, "--fault", root="faults")
    assert config.burst.mean_burst_s is None and config.burst.p_bad_to_good == 0.5


@pytest.mark.parametrize("overrides, message", [
    ({"loss_probability": 2.0}, "--fault: faults.loss_probability: "),
    ({"los_probability": 0.1}, "--fault: faults.los_probability: unknown key (check the spelling)"),
    ({"loss_probability.x": 1}, "--fault loss_probability.x: faults.loss_probability is not a table"),
    ({"blackouts": [{"start": 1.0}]}, "faults.blackouts.0.duration"),
])
def test_the_schema_judges_the_merged_document(overrides, message):
    with pytest.raises(ConfigError) as error:
        apply_overrides(FaultsConfig(), overrides, "--fault", root="faults")
    assert message in str(error.value)
