"""The test-support package itself (decision 0032): the Stack's arguments, ports, a failed start.

The Stack replaced five hand-written ones; the arguments it builds are checked here against the
command lines those wrote out, so a test that moved onto it starts the same processes.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tanklab_testing.procs import TankctlProcess, free_base_port
from tanklab_testing.stack import Stack


def test_stack_arguments_are_the_command_lines_the_tests_wrote_by_hand(tmp_path: Path) -> None:
    cfg, state = tmp_path / "site.yaml", tmp_path / "plant-state.json"
    plant = "opc.tcp://127.0.0.1:20000/tanklab/plant"
    s = Stack(cfg, 20000, speed=5.0, state_file=state)
    assert s.args("plant") == (
        *("plant", "--config", str(cfg), "--speed", "5", "--port", "20000"),
        *("--state-file", str(state)),
    )
    assert s.args("plc", "--trace", "t.csv") == (
        *("plc", "--config", str(cfg), "--speed", "5", "--port", "20001", "--plant-url", plant),
        *("--trace", "t.csv"),
    )
    assert s.args("supervisor") == (
        *("supervisor", "--config", str(cfg), "--speed", "5", "--port", "20002"),
        *("--plc-url", "opc.tcp://127.0.0.1:20001/tanklab/plc"),
    )
    # The benchmarks' variation: --host with the log directory, their own --home.
    b = Stack(cfg, 20000, speed=10.0, home=tmp_path / "home", log_dir=tmp_path, tier_args={"plc": ("-x",)})
    assert b.args("plc") == (
        *("plc", "--config", str(cfg), "--host", "127.0.0.1", "--speed", "10"),
        *("--home", str(tmp_path / "home"), "--port", "20001", "--plant-url", plant, "-x"),
    )
    assert s.urls == [plant, "opc.tcp://127.0.0.1:20001/tanklab/plc", s.supervisor_url]


def test_base_ports_are_never_handed_out_twice() -> None:
    bases = [free_base_port(4) for _ in range(20)]
    ports = [b + k for b in bases for k in range(4)]
    assert len(set(ports)) == len(ports)


@pytest.mark.process
async def test_a_process_that_exits_before_serving_fails_its_start_and_is_gone(tmp_path: Path) -> None:
    proc = TankctlProcess("plant", "--config", str(tmp_path / "missing.yaml"))
    try:
        with pytest.raises(RuntimeError, match="exited before serving"):
            await proc.start()
        assert proc.proc is not None and proc.proc.returncode not in (None, 0)
        assert not proc.running
    finally:
        await proc.cleanup()
