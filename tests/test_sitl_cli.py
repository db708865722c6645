"""sitl-plant's command line and [sitl] configuration: clear errors, overrides, complete logs."""

from __future__ import annotations

import json
import math

import pytest

from interfaces.scenario import ConfigError, load_scenario
from sitl_plant import sitl
from studies.processes import free_port


def _scenario_with(tmp_path, scenario_path, extra: str):
    text = scenario_path("constant_velocity").read_text()
    text = text.replace('vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{scenario_path("constant_velocity").parent.parent / "vehicles" / "paper_table1.toml"}"')
    path = tmp_path / "scenario.toml"
    path.write_text(text + "\n" + extra)
    return path


def test_sitl_section_defaults_are_px4_sitl(scenario_path):
    scenario, _ = load_scenario(scenario_path("constant_velocity"))
    assert scenario.sitl.companion_port == 14540 and scenario.sitl.gcs_port == 14550
    assert scenario.sitl.bind_host == "127.0.0.1"
    assert scenario.sitl.speed_factor == 1.0


@pytest.mark.parametrize(
    "extra, key",
    [
        ("[sitl]\nhome = [95.0, 8.0, 400.0]\n", "sitl"),
        ("[sitl]\nspeed_factor = 0\n", "sitl.speed_factor"),
        ("[sitl]\ncompanion_port = 70000\n", "sitl.companion_port"),
        ("[sitl]\ntick_rate_hz = 300\n", "sitl.tick_rate_hz"),
        ("[sitl]\nspeedfactor = 2\n", "sitl.speedfactor"),
    ],
)
def test_bad_sitl_section_is_rejected_naming_the_key(tmp_path, scenario_path, extra, key):
    with pytest.raises(ConfigError) as error:
        load_scenario(_scenario_with(tmp_path, scenario_path, extra))
    assert key in str(error.value)


def test_parameter_overrides_apply_and_bad_ones_name_the_parameter(tmp_path, scenario_path):
    path = _scenario_with(tmp_path, scenario_path, "[sitl.parameters]\nCOM_OF_LOSS_T = 0.5\nCOM_OBL_RC_ACT = 5\n")
    scenario, vehicle = load_scenario(path)
    mavlink_vehicle = sitl.build_vehicle(scenario, vehicle, companion_port=free_port(), gcs_port=free_port())
    try:
        assert mavlink_vehicle.autopilot.parameters.value("COM_OF_LOSS_T") == 0.5
        assert mavlink_vehicle.autopilot.parameters.value("COM_OBL_RC_ACT") == 5
        assert all(link.address[0] == "127.0.0.1" for link in mavlink_vehicle.links)
    finally:
        mavlink_vehicle.close()
    for bad, fragment in (("NOT_A_PARAM = 1", "NOT_A_PARAM"), ("COM_OBL_RC_ACT = 3", "COM_OBL_RC_ACT"), ("SIM_MASS = 2.0", "read-only")):
        path = _scenario_with(tmp_path, scenario_path, f"[sitl.parameters]\n{bad}\n")
        scenario, vehicle = load_scenario(path)
        with pytest.raises(ConfigError) as error:
            sitl.build_vehicle(scenario, vehicle, companion_port=free_port(), gcs_port=free_port())
        assert fragment in str(error.value)


def test_main_reports_config_errors_with_exit_code_2(tmp_path, capsys):
    assert sitl.main(["--config", str(tmp_path / "missing.toml")]) == 2
    assert "file not found" in capsys.readouterr().err
    assert sitl.main(["--speed-factor", "-1", "--companion-port", str(free_port())]) == 2
    assert "--speed-factor" in capsys.readouterr().err
    assert sitl.main(["--gcs-port", "0"]) == 2


def test_main_runs_for_a_duration_and_leaves_complete_logs(tmp_path, capsys):
    code = sitl.main(["--duration", "2.0", "--speed-factor", "50", "--companion-port", str(free_port()),
                      "--gcs-port", str(free_port()), "--log-dir", str(tmp_path), "--quiet"])
    assert code == 0
    assert "sitl-plant ready" in capsys.readouterr().out
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert stats["sim_time"] == pytest.approx(2.0, abs=0.01)
    assert stats["mavlink"]["rejected"] == {}
    rows = (tmp_path / "vehicle.csv").read_text().splitlines()
    assert rows[0].startswith("time,x,y,z")
    times = [float(row.split(",")[0]) for row in rows[1:]]
    assert len(times) == pytest.approx(100, abs=2)  # 50 Hz for 2 s
    assert all(b > a for a, b in zip(times, times[1:]))
    # At rest on the ground, disarmed, for the whole run.
    assert all(math.isclose(float(row.split(",")[3]), 0.0, abs_tol=1e-9) for row in rows[1:])
