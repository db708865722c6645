"""The argparse types every command shares (interfaces.cli): a folder to write into."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from interfaces.cli import output_folder


def test_a_folder_to_write_into_is_one_that_is_or_can_be_a_folder(tmp_path):
    existing = tmp_path / "runs"
    existing.mkdir()
    a_file = tmp_path / "notes.txt"
    a_file.write_text("x")
    assert output_folder(str(existing)) == existing
    assert output_folder(str(tmp_path / "new" / "deeper")) == tmp_path / "new" / "deeper"  # made when written
    for bad in (a_file, a_file / "inside", a_file / "inside" / "deeper"):
        with pytest.raises(argparse.ArgumentTypeError, match=f"{a_file} exists and is not a folder"):
            output_folder(str(bad))


@pytest.mark.parametrize("command", [["studies.run_scenario", "--out"], ["studies.montecarlo", "--out"],
                                     ["studies.campaign", "--out"], ["studies.swarm_study", "--out"],
                                     ["studies.full_sitl", "--out"], ["companion", "--log-dir"],
                                     ["sitl_plant.sitl", "--log-dir"], ["sitl_plant.world.target_publisher", "--log-dir"]])
def test_every_command_refuses_a_file_as_its_output_folder_before_it_starts(tmp_path, command):
    a_file = tmp_path / "notes.txt"
    a_file.write_text("x")
    done = subprocess.run([sys.executable, "-m", *command, str(a_file)], capture_output=True, text=True, timeout=120,
                          cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].endswith(f"{a_file} exists and is not a folder")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["notes.txt"]
