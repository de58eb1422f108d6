"""station/plc/master.py, the PLC simulator: what it reports about the station it drove."""

import re

import pytest

from station.plc.background import BackgroundServer
from station.plc.device import PlcDevice
from station.plc.master import main as plc_sim_main
from station.plc.runner import dry_run_runner


@pytest.mark.parametrize("heartbeat_s, verdict", [(0.02, "advancing"), (1000.0, "STOPPED")])
def test_the_plc_simulator_reports_the_heartbeat_it_saw(capsys, heartbeat_s, verdict):
    """One quick cycle: the heartbeat is watched for a second, so a stopped one is reported as
    stopped, and "advancing" always shows two different values."""
    with BackgroundServer(PlcDevice(dry_run_runner(0), heartbeat_s=heartbeat_s)) as bg:
        rc = plc_sim_main(["--port", str(bg.start_tcp()), "--cycles", "1", "--quiet"])
    line = capsys.readouterr().out.splitlines()[-1]
    assert f"heartbeat {verdict}" in line, line
    if verdict == "advancing":
        first, last = map(int, re.search(r"\((\d+) -> (\d+)\)", line).groups())
        assert rc == 0 and first != last
    else:
        assert rc == 1
