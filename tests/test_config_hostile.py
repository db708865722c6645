"""Hostile scenario and vehicle files: every one is refused at load time with a ConfigError naming the file (and
the key), never a traceback, a hang or unbounded memory; and the values that would make a flight run forever are
refused by the schema."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import interfaces.scenario as schema
import interfaces.scenario.files as schema_files
from interfaces.overrides import parse_assignment
from interfaces.scenario import (CONFIG_DIR, MAX_CONFIG_BYTES, SCENARIOS_DIR, VEHICLES_DIR, ConfigError,
                                 load_plant_scenario, load_scenario)

VALID = (SCENARIOS_DIR / "constant_velocity.toml").read_text()
VEHICLE_LINE = 'vehicle = "../vehicles/paper_table1.toml"'
ROOT = Path(__file__).resolve().parent.parent


def _write(tmp_path: Path, text: str | bytes, name: str = "case.toml") -> Path:
    vehicles = tmp_path / "vehicles"
    vehicles.mkdir(exist_ok=True)
    (vehicles / "paper_table1.toml").write_text((VEHICLES_DIR / "paper_table1.toml").read_text())
    scenarios = tmp_path / "scenarios"
    scenarios.mkdir(exist_ok=True)
    path = scenarios / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def _refused(path: Path, match: str, loader=load_scenario) -> str:
    """The one-line ConfigError `loader(path)` raises; it names `path` and matches `match`."""
    with pytest.raises(ConfigError, match=match) as error:
        loader(path)
    message = str(error.value)
    assert str(path) in message and "\n" not in message, message
    return message


# --- 1. the file itself ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("loader", [load_scenario, load_plant_scenario])
@pytest.mark.parametrize("content, match", [
    (b'name = "caf\xe9"\n', "not UTF-8"),                               # Latin-1, not UTF-8
    (b"\xff\xfe" + "name = 'x'\n".encode("utf-16-le"), "not UTF-8"),  # UTF-16 with its BOM
    (("v = " + "[" * 5000 + "]" * 5000 + "\n").encode(), "nested too deeply"),
    (("v = " + "{a = " * 3000 + "1" + "}" * 3000 + "\n").encode(), "nested too deeply"),
    (("v = " + "7" * 5000 + "\n").encode(), "integer literal has more than"),
], ids=["latin1", "utf16", "deep-arrays", "deep-inline-tables", "huge-integer"])
def test_unreadable_toml_is_a_config_error(tmp_path, content, match, loader):
    _refused(_write(tmp_path, content), match, loader)


def test_a_directory_is_not_a_scenario(tmp_path):
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    _refused(folder, "not a regular file")
    _refused(folder, "not a regular file", load_plant_scenario)


def test_a_directory_is_not_a_vehicle(tmp_path):
    path = _write(tmp_path, VALID.replace(VEHICLE_LINE, 'vehicle = "../vehicles"'))
    message = _refused(path, "not a regular file")
    assert "vehicle = '../vehicles'" in message


def test_a_permission_error_is_a_config_error(tmp_path, monkeypatch):
    """An unreadable file (the open's PermissionError, raised here by a stand-in open: chmod 0 stops no root user,
    and CI runs as root) becomes a one-line ConfigError."""
    path = _write(tmp_path, VALID)
    real_open = os.open

    def refuse(file, *args, **kwargs):
        if Path(file) == path:
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(os, "open", refuse)
    _refused(path, "permission denied")


def test_a_nul_byte_in_the_vehicle_path_is_a_config_error(tmp_path):
    path = _write(tmp_path, VALID.replace(VEHICLE_LINE, 'vehicle = "a\\u0000b.toml"'))
    with pytest.raises(ConfigError, match="vehicle"):
        load_scenario(path)


def _load_in_child(scenario: Path, loader: str = "load_scenario") -> subprocess.CompletedProcess:
    """`loader(scenario)` in a child with 1 GB of address space and 60 s: a read that blocks or never ends fails
    the test instead of hanging it or filling the machine's memory."""
    code = textwrap.dedent(f"""
        import resource
        resource.setrlimit(resource.RLIMIT_AS, (2**30, 2**30))
        from interfaces.scenario import ConfigError, {loader}
        try:
            {loader}({str(scenario)!r})
        except ConfigError as error:
            print(error)
            raise SystemExit(3)
        """)
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60,
                          check=False)


@pytest.mark.parametrize("loader", ["load_scenario", "load_plant_scenario"])
def test_a_fifo_as_vehicle_is_refused_without_blocking(tmp_path, loader):
    fifo = tmp_path / "vehicles" / "fifo.toml"
    path = _write(tmp_path, VALID.replace(VEHICLE_LINE, 'vehicle = "../vehicles/fifo.toml"'))
    os.mkfifo(fifo)
    result = _load_in_child(path, loader)  # TimeoutExpired (a failure) if the open waits for a writer
    assert result.returncode == 3, result.stderr
    assert "not a regular file" in result.stdout and "fifo.toml" in result.stdout


def test_dev_zero_as_vehicle_is_refused_without_reading_it(tmp_path):
    path = _write(tmp_path, VALID.replace(VEHICLE_LINE, 'vehicle = "/dev/zero"'))
    result = _load_in_child(path)  # MemoryError (a failure) if it is read
    assert result.returncode == 3, result.stderr
    assert "not a regular file" in result.stdout and "/dev/zero" in result.stdout


def test_an_oversize_file_is_refused(tmp_path):
    padding = "#" + "x" * MAX_CONFIG_BYTES + "\n"
    _refused(_write(tmp_path, VALID + padding), "too large")
    _refused(_write(tmp_path, VALID + padding, "other.toml"), "too large", load_plant_scenario)


def test_the_size_cap_is_exact_and_far_above_the_shipped_files(tmp_path, monkeypatch):
    largest = max(path.stat().st_size for path in CONFIG_DIR.rglob("*.toml"))
    assert MAX_CONFIG_BYTES >= max(1000 * largest, 8 * 2**20)  # an 8 MB, 100k-maneuver scenario loads
    path = _write(tmp_path, VALID)
    monkeypatch.setattr(schema_files, "MAX_CONFIG_BYTES", len(VALID.encode()))  # where the reads look it up
    load_scenario(path)
    path.write_text(VALID + "\n")
    _refused(path, "too large")


def test_a_toml_value_python_cannot_read_is_a_config_error_in_an_override():
    for literal in ("[" * 5000 + "]" * 5000, "9" * 5000):
        with pytest.raises(ConfigError, match="--case guidance.c_y"):
            parse_assignment(f"guidance.c_y={literal}", "--case")


# --- 2. the scenario name becomes a run folder --------------------------------------------------------------------

HOSTILE_NAMES = ["../x", "../../escaped", "/abs", "a/b", "a\\b", "", ".", "..", ".hidden", "-rf", "a\x00b", "a\nb",
                 "a b", "x" * 101, "x" * 300, "caf\u00e9", "a:b"]


@pytest.mark.parametrize("loader", [load_scenario, load_plant_scenario])
@pytest.mark.parametrize("name", HOSTILE_NAMES, ids=repr)
def test_a_hostile_name_is_refused(tmp_path, name, loader):
    literal = '"' + name.replace("\\", "\\\\").replace("\x00", "\\u0000").replace("\n", "\\n") + '"'
    path = _write(tmp_path, VALID.replace('name = "constant_velocity"', f"name = {literal}"))
    with pytest.raises(ConfigError, match=r"  name: .*run folders") as error:
        loader(path)
    assert str(path) in str(error.value) and len(str(error.value)) < 400


@pytest.mark.parametrize("path", sorted(SCENARIOS_DIR.glob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_name_is_accepted(path):
    assert load_plant_scenario(path)[0].name == load_scenario(path)[0].name == path.stem


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=120))
def test_an_accepted_name_stays_one_folder_inside_out(name):
    document = {"name": name, "target": {"initial_position": [50.0, 0.0, 0.0], "initial_velocity": [1.0, 0.0, 0.0]},
                "estimator": {"initial_range": 50.0}}
    try:
        scenario = schema.Scenario.model_validate(document)
    except ValueError:
        return
    out = Path("/tmp/out")
    folder = out / f"sitl-{scenario.name}-seed0-20240101-000000"
    assert folder.parent == out and os.path.normpath(folder) == str(folder) and len(folder.name.encode()) <= 255


# --- 3. cross-field checks the companion makes: refused at load time -----------------------------------------------

@pytest.mark.parametrize("extra, replace, keys", [
    ("[health]\nmax_range = 1\n", None, ("health.max_range", "guidance.desired_range")),
    ("", ("desired_range = 8.0", "desired_range = 8000"), ("health.max_range", "guidance.desired_range")),
    ("[dropout]\nmin_range = 20.0\n", None, ("dropout.min_range", "dropout.safe_range")),
    ("[dropout]\nsafe_range = 3.0\n", None, ("dropout.min_range", "dropout.safe_range")),
], ids=["health-max-range", "huge-desired-range", "dropout-min-range", "dropout-safe-range"])
def test_companion_range_limits_are_checked_at_load_time(tmp_path, extra, replace, keys):
    text = VALID if replace is None else VALID.replace(*replace, 1)
    path = _write(tmp_path, text + "\n" + extra)
    with pytest.raises(ConfigError) as error:
        load_scenario(path)
    assert str(path) in str(error.value) and all(key in str(error.value) for key in keys), str(error.value)


@settings(max_examples=200, deadline=None)
@given(desired=st.floats(0.01, 1e5), max_range=st.floats(0.01, 1e5), health_min=st.none() | st.floats(0.0, 1e5),
       dropout_min=st.none() | st.floats(0.01, 1e5), safe=st.none() | st.floats(0.01, 1e5))
def test_an_accepted_scenario_builds_the_companions_health_and_dropout(desired, max_range, health_min, dropout_min,
                                                                       safe):
    from companion.assembly import dropout_policy, health_config

    document = {"name": "x", "target": {"initial_position": [50.0, 0.0, 0.0], "initial_velocity": [1.0, 0.0, 0.0]},
                "estimator": {"initial_range": 50.0}, "guidance": {"desired_range": desired},
                "health": {"max_range": max_range, "min_range": health_min},
                "dropout": {"min_range": dropout_min, "safe_range": safe}}
    try:
        scenario = schema.Scenario.model_validate(document)
    except ValueError:
        return
    health_config(scenario)
    dropout_policy(scenario)


# --- 4.-7. values that make a flight run forever or allocate without bound -------------------------------------------

@pytest.mark.parametrize("section, key, bad, good", [
    ("[target.singer]", "update_period", [1e-300, 1e-4, 9.99e-4], [1e-3, 0.02, 1.0]),
    ("[faults]", "impostor_rate_hz", [1e6, 1000.5, 1e300], [0.0, 5.0, 1000.0]),
    ("[faults]", "spoof_rate_hz", [1e6, 1000.5], [0.0, 1000.0]),
    ("[sitl]", "speed_factor", [0.0, 0.49, 20.01, 100.0], [0.5, 1.0, 20.0]),
    ("[companion]", "follow_duration", [86400.5, 1e300], [1.0, 86400.0]),
])
def test_unbounded_values_are_refused_naming_the_key(tmp_path, section, key, bad, good):
    for value in bad + good:
        path = _write(tmp_path, f"{VALID}\n{section}\n{key} = {value!r}\n")
        if value in good:
            load_scenario(path)
            continue
        with pytest.raises(ConfigError, match=rf"  {section.strip('[]')}.{key}: ") as error:
            load_scenario(path)
        assert str(path) in str(error.value)


@pytest.mark.parametrize("section, key", [("estimator", "rate_hz"), ("sensor", "rate_hz"), ("guidance", "rate_hz"),
                                          ("sitl", "tick_rate_hz")])
def test_a_loop_rate_under_a_hundredth_of_a_hertz_is_refused(tmp_path, section, key):
    # estimator.rate_hz = 1e-300 divides the physics rate "into whole steps" and then overflowed at take-off
    text = VALID if f"[{section}]" in VALID else VALID + f"\n[{section}]\n"
    for value, accepted in ((1e-300, False), (0.0099, False), (0.01, True)):
        edited = text.replace(f"[{section}]\n", f"[{section}]\n{key} = {value!r}\n", 1)
        edited = edited.replace("rate_hz = 50.0\n", "", 1) if section == "estimator" else edited
        edited = edited.replace("rate_hz = 5.0 ", "#", 1) if section == "sensor" else edited
        edited = edited.replace("rate_hz = 20.0\n", "", 1) if section == "guidance" else edited
        path = _write(tmp_path, edited)
        if accepted:
            load_scenario(path)
            continue
        with pytest.raises(ConfigError, match=rf"{section}.{key} = .* must be at least 0.01 Hz"):
            load_scenario(path)
        if section in ("sensor", "sitl"):
            with pytest.raises(ConfigError, match=rf"{section}.{key} = .* must be at least 0.01 Hz"):
                load_plant_scenario(path)


def test_the_speed_factor_bounds_are_bof_sitls():
    from studies.full_sitl import main

    for value in (schema.MIN_SPEED_FACTOR - 0.01, schema.MAX_SPEED_FACTOR + 0.01):
        with pytest.raises(SystemExit) as exit_:
            main(["--speed-factor", str(value)])
        assert exit_.value.code == 2
    assert (schema.MIN_SPEED_FACTOR, schema.MAX_SPEED_FACTOR) == (0.5, 20.0)
