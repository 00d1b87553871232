"""The pytest plugin's ``tanklab_stack`` (tankctl.testing.fixture; issue 18, decision 0056).

- Lock-step, on the three-tank site with its supervisor (tanks started at the setpoints through
  the site overrides, which the tiers read from a written file): an operator's setpoint written
  over OPC UA in an async test moves the level toward it in model time; an observer's write is
  refused with one line naming the status; the supervisor tier runs and serves.
- :func:`running_stack` stops every process it started when its block ends, also when the
  block raises.
- Bad options fail with one line naming the option.
- The repository's Stack is the shipped one (one code path), run from the repository root.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from helpers import ROOT
from tankctl.testing.fixture import RunningStack, StackError, StackOptions, running_stack
from tankctl.testing.logins import Logins
from tanklab.config import load_site
from tanklab_testing.procs import alive

ENERGIES = ROOT / "configs" / "three_tank_energies_sim.yaml"
SINGLE = ROOT / "configs" / "single_tank_short_sim.yaml"


@pytest.mark.tanklab_site(
    config=str(ENERGIES),
    overrides={"plant.tanks.0.initial_level_m": 0.4, "plant.tanks.1.initial_level_m": 0.2},
)
@pytest.mark.tanklab_stack(clock="lockstep", role="operator")
async def test_a_setpoint_written_in_an_async_test_moves_the_level_toward_it(
    tanklab_stack: RunningStack,
) -> None:
    assert tanklab_stack.tiers == ("plant", "plc", "supervisor")
    async with tanklab_stack.connect("plc") as plc:
        await plc.advance(5.0)
        got = await plc.read_many(["PLC.LIC1.PV", "PLC.LIC1.SP"])
        target_m = got["PLC.LIC1.SP"] + 0.03
        before_m = abs(got["PLC.LIC1.PV"] - target_m)
        await plc.write("PLC.LIC1.SP", target_m)
        assert await plc.read("PLC.LIC1.SP") == pytest.approx(target_m)
        await plc.advance(200.0)
        after_m = abs(await plc.read("PLC.LIC1.PV") - target_m)
    assert after_m < before_m / 2  # the real PLC, in lock-step, moved the level toward the new SP
    async with tanklab_stack.connect("supervisor", "observer") as sup:
        assert await sup.read("Supervisor.Mode") is not None


@pytest.mark.tanklab_site(config=str(SINGLE))
def test_a_refused_write_and_a_wrong_path_fail_in_one_line(
    tanklab_stack_factory: Callable[..., RunningStack],
) -> None:
    stack = tanklab_stack_factory(role="observer")
    assert stack.tiers == ("plant", "plc")  # the single-tank site has no supervisor
    with pytest.raises(StackError, match=r"^tanklab_stack: write PLC.LIC1.SP = 0.1 refused: Bad\w+$"):
        stack.plc.write("PLC.LIC1.SP", 0.1)
    with pytest.raises(StackError, match=r"has no tag 'PLC\.LIC9\.SP'"):
        stack.plc.read("PLC.LIC9.SP")
    with pytest.raises(StackError, match="no supervisor in this stack"):
        stack.client("supervisor")
    engineer = stack.client("plc", "engineer")
    engineer.write("PLC.LIC1.SP", 0.1)
    assert stack.plc.read("PLC.LIC1.SP") == pytest.approx(0.1)  # the observer reads what was written


def test_every_process_is_stopped_when_the_block_ends_or_raises(
    tanklab_logins: Logins, tmp_path: Path
) -> None:
    site = load_site(SINGLE)
    pids: list[int] = []
    with (
        pytest.raises(RuntimeError, match="the test failed"),
        running_stack(site, SINGLE, tanklab_logins, tmp_path, StackOptions()) as stack,
    ):
        pids = [stack.stack.pid(t) for t in stack.tiers]
        assert all(alive(p) for p in pids)
        assert stack.advance(1.0) >= 1.0
        raise RuntimeError("the test failed")
    assert len(pids) == 2
    assert not any(alive(p) for p in pids)
    assert (tmp_path / "logs" / "plc-0.log").is_file()  # the logs stay for a failed test


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"clock": "fast"}, "clock must be one of lockstep, realtime, got 'fast'"),
        ({"clock": "lockstep", "speed": 5.0}, "speed is for clock='realtime'"),
        ({"clock": "realtime", "speed": -1.0}, "speed must be a positive number, got -1.0"),
        ({"role": "admin"}, "role must be one of observer, operator, engineer, got 'admin'"),
    ],
)
def test_bad_options_fail_in_one_line(options: dict[str, object], message: str) -> None:
    with pytest.raises(StackError, match=message) as e:
        StackOptions(**options)  # type: ignore[arg-type]
    assert "\n" not in str(e.value)


def test_the_repository_stack_is_the_shipped_one_run_from_the_root(tmp_path: Path) -> None:
    from tankctl.testing import stack as shipped
    from tanklab_testing.stack import Stack

    s = Stack(SINGLE, 20000)
    assert isinstance(s, shipped.Stack)  # one code path: start, kill, down are the plugin's
    assert s.cwd == ROOT
    assert shipped.Stack(SINGLE, 20000).cwd is None  # from a wheel: the caller's directory


def test_lockstep_control_tiers_and_the_historian_store_are_in_the_tier_arguments(tmp_path: Path) -> None:
    from tankctl.testing.fixture import tier_args

    tiers = ["plant", "plc", "supervisor", "historian"]
    locked = tier_args(StackOptions(historian=True), tiers, tmp_path)
    assert locked == {
        "plant": ("--lockstep",),
        "plc": ("--lockstep",),
        "supervisor": ("--lockstep",),
        "historian": ("--store", str(tmp_path / "history.db")),
    }
    assert tier_args(StackOptions(clock="realtime", speed=5.0), tiers[:2], tmp_path) == {}
