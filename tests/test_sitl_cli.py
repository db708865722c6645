"""sitl-plant's command line and [sitl] configuration: clear errors, overrides, complete logs."""

from __future__ import annotations

import json
import math
import signal

import pytest

from interfaces.scenario import ConfigError, load_plant_scenario, load_scenario
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
    code = sitl.main(["--duration", "2.0", "--speed-factor", "20", "--companion-port", str(free_port()),
                      "--gcs-port", str(free_port()), "--log-dir", str(tmp_path), "--quiet"])
    assert code == 0
    assert "sitl-plant ready" in capsys.readouterr().out
    # the loop's dead man's switch is cleared on the way out: nothing is left to end this process later
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
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


def _without_the_companion_sections(tmp_path, scenario_path, broken: str):
    """constant_velocity with its [estimator] and [guidance] replaced by `broken`."""
    text = scenario_path("constant_velocity").read_text()
    kept = text[: text.index("[estimator]")] + broken + "\n" + text[text.index("[simulation]"):]
    vehicle = scenario_path("constant_velocity").parent.parent / "vehicles" / "paper_table1.toml"
    path = tmp_path / "plant_only.toml"
    path.write_text(kept.replace('vehicle = "../vehicles/paper_table1.toml"', f'vehicle = "{vehicle}"'))
    return path


BROKEN_COMPANION_SECTIONS = {
    "missing": "",  # no [estimator] at all: the companion's schema requires one
    "broken": '[estimator]\nkind = "bogus"\nrate_hz = -1\n\n[guidance]\nlaw = "none"\n\n[dropout]\ncoast_after = "x"\n',
}


@pytest.mark.parametrize("broken", BROKEN_COMPANION_SECTIONS.values(), ids=BROKEN_COMPANION_SECTIONS.keys())
def test_the_plant_starts_without_the_companions_sections_and_the_companion_refuses_them(tmp_path, scenario_path,
                                                                                        capsys, broken):
    from companion import app
    from sitl_plant.world import target_publisher
    from studies import run_scenario

    path = _without_the_companion_sections(tmp_path, scenario_path, broken)
    code = sitl.main(["--config", str(path), "--duration", "0.5", "--speed-factor", "20", "--quiet",
                      "--companion-port", str(free_port()), "--gcs-port", str(free_port())])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "sitl-plant ready: constant_velocity" in out.out
    # sitl-target reads the scenario too: it gets past it and stops at the first bad argument.
    assert target_publisher.main(["--config", str(path), "--rate", "-1"]) == 2
    assert "--rate" in capsys.readouterr().err
    # bof-sim and the companion need those sections and say which one is wrong.
    assert run_scenario.main([str(path), "--out", str(tmp_path / "runs")]) == 2
    assert "estimator" in capsys.readouterr().err
    assert app.main(["--config", str(path)]) == 2
    assert "estimator" in capsys.readouterr().err


def test_the_plant_still_checks_its_own_sections(tmp_path, scenario_path):
    path = _without_the_companion_sections(tmp_path, scenario_path, "")
    path.write_text(path.read_text() + "\n[sitl]\nspeed_factor = 0\n")
    with pytest.raises(ConfigError, match="sitl.speed_factor"):
        load_plant_scenario(path)
    path.write_text(path.read_text().replace("[sitl]\nspeed_factor = 0", "[sensor.camera]\nfocal_length = -1\nbogus = 2"))
    load_plant_scenario(path)  # the camera is the companion's business
    path.write_text(path.read_text() + "\n[faults]\nloss_probability = 2.0\n")
    with pytest.raises(ConfigError, match="faults.loss_probability"):
        load_plant_scenario(path)
    path.write_text(path.read_text().replace("[faults]", "[fautls]"))
    with pytest.raises(ConfigError, match="fautls"):
        load_plant_scenario(path)


# ------------------------------------------------------------------ bof-sitl, bof-sim, companion, bof-observability


def _usage_error(main, argv, capsys) -> str:
    """Run a CLI's main expecting argparse's usage error: exit status 2, one error line, no traceback."""
    with pytest.raises(SystemExit) as exited:
        main(argv)
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return [line for line in err.splitlines() if ": error: " in line][0]


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--fault", "nonsense=1"], "faults.nonsense"),
        (["--fault", "los_probability=0.3"], "faults.los_probability"),  # misspelt loss_probability
        (["--fault", "loss_probability=2"], "faults.loss_probability"),
        (["--fault", "loss_probability"], "--fault"),
        (["--timeout", "3"], "--timeout 3 s is too short"),
        (["--abort-after", "-3"], "--abort-after"),
        (["--abort-after", "0"], "--abort-after"),
        (["--seed", "-1"], "--seed"),
        (["--gcs-port", "0"], "--gcs-port"),
        (["--speed-factor", "100"], "--speed-factor"),
        (["config/scenarios"], "is a folder"),
        (["no/such/scenario.toml"], "no such file"),
    ],
)
def test_bof_sitl_refuses_bad_arguments_in_one_line_before_making_anything(tmp_path, capsys, argv, fragment):
    from studies import full_sitl

    out = tmp_path / "runs"
    line = _usage_error(full_sitl.main, [*argv, "--out", str(out)], capsys)
    assert line.startswith("bof-sitl: error:") and fragment in line, line
    assert not out.exists()  # no partial run folder


@pytest.mark.parametrize(
    "argv, fragment",
    [(["--seed", "-1"], "--seed"), (["config/scenarios"], "is a folder"), (["nope.toml"], "no such file")],
)
def test_bof_sim_refuses_bad_arguments_in_one_line(tmp_path, capsys, argv, fragment):
    from studies import run_scenario

    out = tmp_path / "runs"
    line = _usage_error(run_scenario.main, [*argv, "--out", str(out)], capsys)
    assert line.startswith("bof-sim: error:") and fragment in line, line
    assert not out.exists()


@pytest.mark.parametrize(
    "argv, fragment",
    [(["--flight", "nope.toml"], "no such file"), (["--flight", "config/scenarios"], "is a folder"),
     (["--seed", "-1"], "--seed")],
)
def test_bof_observability_refuses_bad_arguments_in_one_line(tmp_path, capsys, argv, fragment):
    from studies import observability_figures

    out = tmp_path / "runs"
    line = _usage_error(observability_figures.main, [*argv, "--out", str(out)], capsys)
    assert line.startswith("bof-observability: error:") and fragment in line, line
    assert not out.exists()


@pytest.mark.parametrize(
    "argv, fragment",
    [(["--config", "config/scenarios"], "is a folder"), (["--config", "nope.toml"], "no such file"),
     (["--seed", "-1"], "--seed")],
)
def test_companion_refuses_bad_arguments_in_one_line(tmp_path, capsys, argv, fragment):
    from companion import app

    line = _usage_error(app.main, [*argv, "--log-dir", str(tmp_path / "log")], capsys)
    assert line.startswith("companion: error:") and fragment in line, line
    assert not (tmp_path / "log").exists()


def test_termination_names_are_the_documented_ones():
    from studies.closed_loop import Termination
    from studies.metrics import termination_name

    names = {termination_name(t) for t in Termination}
    assert {"completed", "aborted", "failsafe", "interrupted", "diverged"} <= names


@pytest.mark.parametrize("endpoint", ["bogus", "tcp/127.0.0.1", "tcp/:7447"])
def test_companion_refuses_a_malformed_endpoint_in_one_line_before_making_anything(tmp_path, capsys, endpoint):
    # It used to say so only with --zenoh-tls; without it the app started and died in a 37-line traceback.
    from companion import app

    assert app.main(["--zenoh-connect", endpoint, "--log-dir", str(tmp_path / "log")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"companion: Zenoh endpoint {endpoint!r}: expected <protocol>/<host>:<port>, e.g. tcp/127.0.0.1:7447"]
    assert not (tmp_path / "log").exists()


@pytest.mark.parametrize("rate", ["0", "nan", "1e300", "1000.5"])
def test_sitl_target_rate_is_bounded(capsys, rate):
    from sitl_plant.world import target_publisher

    assert target_publisher.main(["--rate", rate]) == 2
    assert "--rate" in capsys.readouterr().err
