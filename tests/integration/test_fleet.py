"""``tankctl fleet`` through real processes: 3 sites up, each site's setpoint written through its
own PLC endpoint with the others read back unchanged, ``fleet status``, ``fleet down`` with no
process left (by pid), bad input refused before anything starts, and a hosting process that
keeps its other sites when one fails (decision 0057).
"""

from __future__ import annotations

import asyncio
import logging
import socket
from pathlib import Path

import pytest
from asyncua import ua

from helpers import ROOT, free_base_port, secure, session_home, wait_until
from tankctl.fleet_host import Host, SiteLogs
from tankctl.fleet_layout import FleetLayout
from tanklab import paths
from tanklab.config import load_site
from tanklab_io.ua_client import resolve
from tanklab_io.ua_security import ServerSecurity
from tanklab_testing.procs import TankctlProcess, alive

CONFIG = ROOT / "configs/three_tank_energies_sim.yaml"
pytestmark = pytest.mark.process


def fleet_up(base: int, fleet_dir: Path, *extra: str) -> TankctlProcess:
    args = ["fleet", "up", "--config", str(CONFIG), "--base-port", str(base), "--fleet-dir", str(fleet_dir)]
    return TankctlProcess(
        *args,
        *extra,
        name="fleet-up",
        ready="started: ",
        merge_stderr=True,
        ready_timeout_s=400.0,
        stop_timeout_s=90.0,
    )


async def tankctl(*args: str) -> tuple[int, list[str]]:
    proc = TankctlProcess(*args, ready=None, merge_stderr=True)
    await proc.launch()
    assert proc.proc is not None
    code = await asyncio.wait_for(proc.proc.wait(), 300)
    await proc.stop()
    return code, proc.lines


async def read(url: str, path: str) -> object:
    async with await secure(url, timeout_s=20.0) as client:
        node = (await resolve(client, [path]))[path]
        return await node.read_value()


async def write_sp(url: str, path: str, value: float) -> None:
    async with await secure(url, timeout_s=20.0) as client:
        node = (await resolve(client, [path]))[path]
        await node.write_value(ua.DataValue(ua.Variant(value, ua.VariantType.Double)))


async def test_three_sites_up_each_setpoint_its_own_status_and_down_leaves_nothing(tmp_path: Path) -> None:
    base = free_base_port(9)
    fleet_dir = tmp_path / "fleet"
    up = fleet_up(base, fleet_dir, "--sites", "3", "--sites-per-process", "2")
    try:
        await up.start()
        layout = FleetLayout.load(fleet_dir)
        assert layout.processes == 2
        pids = [int(layout.host_pid_file(j).read_text()) for j in range(2)]
        sp = paths.plc.loop("LIC1").sp
        names = [await read(layout.url(i, "plc"), "PLC.Identity.SiteName") for i in range(3)]
        assert names == [f"three_tank_energies_sim-{i:03d}" for i in range(3)]
        before = [float(await read(layout.url(i, "plc"), sp)) for i in range(3)]  # type: ignore[arg-type]
        wanted = list(before)
        for i in range(3):
            wanted[i] = round(before[i] + 0.01 * (i + 1), 6)
            await write_sp(layout.url(i, "plc"), sp, wanted[i])
            got = [float(await read(layout.url(k, "plc"), sp)) for k in range(3)]  # type: ignore[arg-type]
            # site i has its new setpoint; every other site what it had
            assert got == pytest.approx(wanted), (i, got, wanted)
        code, lines = await tankctl("fleet", "status", "--fleet-dir", str(fleet_dir))
        print("\n".join(lines))
        assert code == 0, lines
        assert any(ln.startswith("sites: 3 of 3 up, 0 failed, 3 reachable") for ln in lines), lines
        assert sum(ln.startswith("host-") and "RSS" in ln for ln in lines) == 2, lines
        assert any(ln.startswith("PLC overruns: ") for ln in lines), lines
        code, lines = await tankctl("fleet", "down", "--fleet-dir", str(fleet_dir))
        print("\n".join(lines))
        assert code == 0, lines
        assert lines[-1].endswith("0 processes left"), lines
        assert up.proc is not None
        assert await asyncio.wait_for(up.proc.wait(), 60) == 0, up.lines
        await wait_until(lambda: not any(alive(p) for p in pids), 30, what="no hosting process left")
        assert not list(fleet_dir.glob("**/*.pid"))
        assert up.lines[-1].startswith("stopped in "), up.lines
        for i in range(3):  # each site's own state and log
            assert (layout.site_dir(i) / "plant-state.json").is_file()
            assert (layout.site_dir(i) / "plc-retain.json").is_file()
            assert layout.site_name(i) in (layout.site_dir(i) / "site.log").read_text()
    finally:
        await up.cleanup()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (("--sites", "0"), "tankctl: --sites must be at least 1, got 0"),
        (
            ("--sites", "3", "--sites-per-process", "0"),
            "tankctl: --sites-per-process must be at least 1, got 0",
        ),
        (("--sites", "30000"), "needs ports"),
    ],
)
async def test_bad_options_one_line_nothing_started(
    tmp_path: Path, extra: tuple[str, ...], message: str
) -> None:
    code, lines = await tankctl(
        "fleet", "up", "--base-port", str(free_base_port(9)), "--fleet-dir", str(tmp_path / "f"), *extra
    )
    assert code == 2, lines
    assert len(lines) == 1 and message in lines[0], lines
    assert not (tmp_path / "f").exists()


async def test_a_busy_port_is_one_line_before_anything_starts(tmp_path: Path) -> None:
    base = free_base_port(9)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", base + 4))  # site 1's PLC
        busy.listen()
        code, lines = await tankctl(
            "fleet", "up", "--sites", "3", "--base-port", str(base), "--fleet-dir", str(tmp_path / "f")
        )
    assert code == 2, lines
    assert lines == [
        f"tankctl: port {base + 4} on 127.0.0.1 is already in use; "
        "nothing started (--base-port picks other ports)"
    ]
    assert not (tmp_path / "f").exists()


async def test_a_failing_site_is_logged_and_the_others_go_on(tmp_path: Path) -> None:
    base = free_base_port(6)
    layout = FleetLayout(tmp_path / "fleet", CONFIG, sites=2, base_port=base, per_process=2)
    host = Host(layout, 0, load_site(CONFIG), ServerSecurity(session_home()))
    stop = asyncio.Event()
    files = {i: layout.site_dir(i) / "site.log" for i in range(2)}
    layout.site_dir(0).mkdir(parents=True)
    layout.site_dir(1).mkdir(parents=True)
    router = SiteLogs(files, logging.NullHandler())  # the hosting process's routing, beside pytest's
    logging.getLogger().addHandler(router)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", layout.port(1, "plc")))  # site 1's PLC cannot serve
        busy.listen()
        task = asyncio.create_task(host.run(stop))
        try:
            await wait_until(
                lambda: host.states[0].state == "up" and host.states[1].state == "failed",
                240,
                what="0 up, 1 failed",
            )
            assert "OSError" in host.states[1].error or "Errno" in host.states[1].error, host.states[1].error
            scans = host.states[0].plc.scans
            await wait_until(lambda: host.states[0].plc.scans >= scans + 2, 30, what="site 0 scanning on")
            assert await read(layout.url(0, "plc"), "PLC.Identity.SiteName") == layout.site_name(0)
        finally:
            stop.set()
            await asyncio.wait_for(task, 90)
            logging.getLogger().removeHandler(router)
            router.close()
    assert "site-001 failed; the other sites go on" in files[1].read_text()
    assert "the other sites go on" not in files[0].read_text()
    assert host.states[0].state == "stopped"
