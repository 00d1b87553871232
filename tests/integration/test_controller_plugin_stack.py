"""A user's supervisory controller loaded by dotted path in the real supervisor process
(``tankctl supervisor --controller``) against the PLC and plant processes in lock-step: the same
system, scan by scan, as the co-simulation running it through the same host; a controller that
starts raising is contained and the PLC's watchdog sheds its loops as for a lost supervisor.
Assertions are on the PLC's trace (indexed by its scan counter) and on the published
``Supervisor.Controller.*`` nodes.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from helpers import ROOT, secure, wait_until
from tankctl.cosim import CoSimulation
from tanklab.config import load_site
from tanklab.enums import LoopMode
from tanklab_io.ua_client import read_values, resolve
from tanklab_testing.procs import free_base_port
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

FIXTURES = ROOT / "tests" / "fixtures"
SCANS = 60
PARAMS = {"kp": 5e-4, "ki": 1e-5, "u_ff": {"LIC1": 2e-5, "LIC2": 1e-5}}


@pytest.fixture(autouse=True)
def user_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """The user's package on this process's path too (the co-simulation side)."""
    monkeypatch.syspath_prepend(str(FIXTURES))


def _site(tmp_path: Path, controller: Mapping[str, Any]) -> Path:
    data = yaml.safe_load((ROOT / "configs" / "three_tank_energies_sim.yaml").read_text())
    for i, level in enumerate((0.36, 0.17, 0.27)):
        data["plant"]["tanks"][i]["initial_level_m"] = level
    data["supervisor"]["controller"] = dict(controller)
    path = tmp_path / "site.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _stack(tmp_path: Path, config: Path, cls: str) -> tuple[Stack, Path]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(FIXTURES), env.get("PYTHONPATH", "")) if p)
    trace = tmp_path / "plc.csv"
    stack = Stack(
        config,
        free_base_port(3),
        state_file=tmp_path / "plant.json",
        env=env,
        tier_args={
            "plant": ("--lockstep",),
            "plc": ("--lockstep", "--trace", str(trace)),
            "supervisor": ("--lockstep", "--controller", cls),
        },
    )
    return stack, trace


def _rows(trace: Path) -> tuple[list[str], list[list[float]]]:
    lines = trace.read_text().splitlines() if trace.exists() else []
    if not lines:
        return [], []
    return lines[0].split(","), [[float(x) for x in ln.split(",")] for ln in lines[1:] if ln.count(",")]


async def test_a_dotted_path_controller_gives_the_cosimulations_trace_in_lockstep(tmp_path: Path) -> None:
    cls = "user_ctrl.pi_ff:PiFeedforward"
    config = _site(tmp_path, {"class": cls, "params": PARAMS})
    stack, trace = _stack(tmp_path, config, cls)
    try:
        await stack.up()
        await wait_until(lambda: len(_rows(trace)[1]) > SCANS, 120, what=f"{SCANS} lock-step scans traced")
        async with await secure(stack.supervisor_url) as client:
            names = ["Class", "Errors", "Overruns", "Diagnostics.Phase", "Diagnostics.Saturated"]
            paths = [f"Supervisor.Controller.{n}" for n in names]
            nodes = await resolve(client, paths)
            published = dict(zip(names, await read_values(client, [nodes[p] for p in paths]), strict=True))
    finally:
        await stack.down()
    head, rows = _rows(trace)
    got = np.array(rows[:SCANS])
    site = load_site(config)
    sim = CoSimulation(site, supervisor_mode="ADVISORY")
    tr = sim.run(float(SCANS))
    n_t, n_p = len(site.tank_names), len(site.pump_names)
    assert got[:, 0].tolist() == list(range(1, SCANS + 1))
    np.testing.assert_array_equal(got[:, 1], np.array(tr.t_s))
    np.testing.assert_array_equal(got[:, 2 : 2 + n_t], tr.array("readings_m"), err_msg="levels read")
    np.testing.assert_array_equal(got[:, 2 + n_t : 2 + n_t + n_p], tr.array("commands"), err_msg="commands")
    modes = got[:, [head.index(f"{lp}_Mode") for lp in site.loop_names]]
    np.testing.assert_array_equal(modes, tr.array("modes"), err_msg="loop modes")
    assert float(LoopMode.REMOTE) in modes  # the user's class drove the pumps through RemoteMV
    assert np.ptp(tr.array("commands"), axis=0).max() > 0.0
    assert published == {
        "Class": cls,
        "Errors": 0,
        "Overruns": 0,
        "Diagnostics.Phase": "driving",
        "Diagnostics.Saturated": published["Diagnostics.Saturated"],
    }
    assert isinstance(published["Diagnostics.Saturated"], bool)


async def test_a_raising_controller_is_contained_and_the_plc_sheds_its_loops(tmp_path: Path) -> None:
    cls = "user_ctrl.pi_ff:RaisesAfter"
    config = _site(tmp_path, {"class": cls, "params": {**PARAMS, "good_steps": 5}, "max_failures": 3})
    stack, trace = _stack(tmp_path, config, cls)
    site = load_site(config)

    def shed() -> bool:
        head, rows = _rows(trace)
        if not rows:
            return False
        col = head.index("LIC1_Mode")
        seen = [int(r[col]) for r in rows]
        return int(LoopMode.REMOTE) in seen and seen[-1] == int(LoopMode.AUTO)

    try:
        await stack.up()
        await wait_until(shed, 120, what="LIC1 in REMOTE, then shed to AUTO by the PLC's watchdog")
        async with await secure(stack.plc_url) as client:
            nodes = await resolve(client, ["PLC.Supervisor.Alive"])
            (alive,) = await read_values(client, list(nodes.values()))
        async with await secure(stack.supervisor_url) as client:
            paths = ["Supervisor.Controller.Errors", "Supervisor.Controller.LastError"]
            nodes = await resolve(client, paths)
            errors, last_error = await read_values(client, [nodes[p] for p in paths])
    finally:
        await stack.down()
    head, rows = _rows(trace)
    col = [head.index(f"{lp}_Mode") for lp in site.loop_names]
    modes = np.array(rows)[:, col]
    first_remote = int(np.argmax(modes[:, 0] == float(LoopMode.REMOTE)))
    assert first_remote <= 2  # the first step put the loops in REMOTE
    assert alive is False
    assert errors >= 3
    assert last_error.startswith("raised: RuntimeError: user bug at t = ")
    assert stack.exited == {}  # the supervisor kept running: contained, not crashed
