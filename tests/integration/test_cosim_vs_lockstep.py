"""The co-simulation and the three processes in lock-step are the same system, scan by scan.

Both run the supervisor through :class:`supervisor.port.SupervisorDriver` and send its requests
in the order of :class:`supervisor.port.PlcRequest` (in-process: ``tankctl.cosim.ProgramPort``;
over OPC UA: ``supervisor.link.PlcLink``). So with the MPC driving the pumps through RemoteMV,
the levels the PLC read, the commands it wrote, the loop modes and the MPC's whole plans must
agree at every scan: any difference of order or timing between the two paths shows here.
Assertions are on the traces' values, indexed by the PLC's scan counter.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from helpers import ROOT, TierProcess, free_base_port, wait_until
from tankctl.cosim import CoSimulation
from tanklab.config import load_site
from tanklab.enums import LoopMode

pytestmark = pytest.mark.process

SCANS = 120


def _mpc_site(tmp_path: Path, base: str, edits: dict[str, object]) -> Path:
    data = yaml.safe_load((ROOT / "configs" / base).read_text())
    data["supervisor"]["mode"] = "MPC"
    for dotted, value in edits.items():
        *head, last = dotted.split(".")
        node = data
        for key in head:
            node = node[int(key)] if isinstance(node, list) else node[key]
        node[last] = value
    path = tmp_path / "site.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


async def _lockstep(tmp_path: Path, config: Path) -> tuple[list[list[float]], list[str], list[list[float]]]:
    base = free_base_port()
    urls = [
        f"opc.tcp://127.0.0.1:{base + k}/tanklab/{t}" for k, t in enumerate(("plant", "plc", "supervisor"))
    ]
    common = ("--config", str(config), "--lockstep")
    plc_trace, sup_trace = tmp_path / "plc.csv", tmp_path / "supervisor.csv"
    procs = [
        await TierProcess(
            "plant", *common, "--port", str(base), "--state-file", str(tmp_path / "s.json")
        ).start(),
        await TierProcess(
            "plc", *common, "--port", str(base + 1), "--plant-url", urls[0], "--trace", str(plc_trace)
        ).start(),
        await TierProcess(
            "supervisor", *common, "--port", str(base + 2), "--plc-url", urls[1], "--trace", str(sup_trace)
        ).start(),
    ]
    try:
        await wait_until(
            lambda: plc_trace.exists() and len(plc_trace.read_text().splitlines()) > SCANS + 1,
            120,
            what=f"{SCANS} lock-step scans traced",
        )
    finally:
        for p in reversed(procs):
            await p.stop()
    lines = plc_trace.read_text().splitlines()
    head = lines[0].split(",")
    plc_rows = [[float(x) for x in line.split(",")] for line in lines[1 : SCANS + 1]]
    sup_rows = [[float(x) for x in line.split(",")] for line in sup_trace.read_text().splitlines() if line]
    return plc_rows, head, sup_rows


def _cosim(config: Path) -> tuple[CoSimulation, dict[int, np.ndarray]]:
    site = load_site(config)
    sim = CoSimulation(site, supervisor_mode="MPC")
    plans: dict[int, np.ndarray] = {}
    for _ in range(SCANS):
        sim.step()
        sup = sim.supervisor
        assert sup is not None
        if sup.result is not None and sup.result_scan == sim.plc.scan_count:
            plans[sim.plc.scan_count] = np.array(sup.result.planned_u).ravel()
    return sim, plans


@pytest.mark.parametrize(
    ("base", "edits"),
    [
        # the MPC samples every 1 s PLC scan; the tanks start below the setpoints (not empty, where
        # the pumps would sit at their limits for the whole run)
        (
            "three_tank_energies_sim.yaml",
            {
                "plant.tanks.0.initial_level_m": 0.36,
                "plant.tanks.1.initial_level_m": 0.17,
                "plant.tanks.2.initial_level_m": 0.27,
            },
        ),
        # the ABB rig's shape: PLC at 0.5 s under a 2.5 s MPC, a 5 cm step of h1 pending at start
        (
            "three_tank_kortela.yaml",
            {
                "plc.scan_period_s": 0.5,
                "supervisor.sample_time_s": 2.5,
                "supervisor.mpc.du_max_m3_s": 1.0e-5,
                "plc.loops.0.setpoint_m": 0.4537,
            },
        ),
    ],
    ids=["energies-every-scan", "kortela-plc-0.5s-mpc-2.5s"],
)
async def test_cosimulation_and_lockstep_processes_agree_scan_by_scan(
    tmp_path: Path, base: str, edits: dict[str, object]
) -> None:
    config = _mpc_site(tmp_path, base, edits)
    plc_rows, head, sup_rows = await _lockstep(tmp_path, config)
    sim, plans = _cosim(config)
    site = sim.site
    tr = sim.trace
    n_t, n_p = len(site.tank_names), len(site.pump_names)
    got = np.array(plc_rows)
    assert got[:, 0].tolist() == list(range(1, SCANS + 1))
    np.testing.assert_array_equal(got[:, 1], np.array(tr.t_s))
    np.testing.assert_array_equal(got[:, 2 : 2 + n_t], tr.array("readings_m"), err_msg="levels read")
    np.testing.assert_array_equal(got[:, 2 + n_t : 2 + n_t + n_p], tr.array("commands"), err_msg="commands")
    modes = got[:, [head.index(f"{lp}_Mode") for lp in site.loop_names]]
    np.testing.assert_array_equal(modes, tr.array("modes"), err_msg="loop modes")
    assert float(LoopMode.REMOTE) in modes  # the MPC drove the pumps through RemoteMV
    # The MPC's plans, sample by sample (the lock-step trace may run a few samples past SCANS).
    lock_plans = {int(r[0]): np.array(r[3:]) for r in sup_rows if int(r[0]) <= SCANS}
    assert sorted(lock_plans) == sorted(plans)
    assert len(plans) == SCANS // site.supervisor_sample_scans
    for scan, plan in plans.items():
        np.testing.assert_array_equal(lock_plans[scan], plan, err_msg=f"MPC plan at scan {scan}")
    # the commands moved: the comparison is of a transient, not of a plant at rest
    assert np.ptp(tr.array("commands"), axis=0).max() > 0.0
