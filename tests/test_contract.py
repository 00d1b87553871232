"""The contract used through its builders: no node path spelled outside ``tanklab.paths``, and
exactly one handler per writable tag in each tier's server.

Node paths are built by :mod:`tanklab.paths` (``plant.lt("T1").pv``); a string literal or
f-string that starts like a node path (``"PLC.LIC1.SP"``, ``f"Plant.{name}.Leak"``,
``"PLC.%s.SetGains"``) anywhere else in ``src`` retypes the contract. Docstrings and bare string
statements are prose, not paths, and are not counted. Every file is converted: there is no
allow-list.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path
from typing import Any, cast

import pytest

from plant_sim.plant import PlantSimulator
from plant_sim.server import PlantServer
from plc_emulator.program import PlcProgram
from plc_emulator.publish import status_values
from plc_emulator.server import PlcServer
from plc_emulator.writes import apply_write, program_writes
from supervisor.cycle import SupervisorCore
from supervisor.server import SupervisorServer
from tanklab import paths
from tanklab.config import load_site
from tanklab.handlers import HandlerTable, check_handlers, methods_of, writable_variables
from tanklab.tags import Tag, plant_tags, plc_tags, supervisor_tags

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))

CONTRACT = {"tanklab/paths.py"}
"""Where node paths are spelled."""

TEST_SUPPORT = "tanklab_testing/"
"""Not shipped (decision 0032): its fuzzers spell wrong and made-up node paths on purpose."""

_PATH_START = re.compile(r"^(Plant|PLC|Supervisor)\.[A-Za-z{%]")
_FSTRING_START = re.compile(r"^(Plant|PLC|Supervisor)\.")


def path_literals(source: str) -> list[tuple[int, str]]:
    """(line, text) of every string or f-string of ``source`` that starts like a node path;
    docstrings and other bare string statements left out."""
    tree = ast.parse(source)
    prose = {
        id(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant | ast.JoinedStr)
    }
    inner = {id(v) for node in ast.walk(tree) if isinstance(node, ast.JoinedStr) for v in node.values}
    found = []
    for node in ast.walk(tree):
        if id(node) in prose or id(node) in inner:
            continue
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and _PATH_START.match(node.value):
            found.append((node.lineno, node.value))
        elif isinstance(node, ast.JoinedStr) and node.values:
            head = node.values[0]
            text = head.value if isinstance(head, ast.Constant) else None
            if isinstance(text, str) and _FSTRING_START.match(text):
                found.append((node.lineno, ast.unparse(node)))
    return sorted(found)


def test_the_scanner_finds_literals_and_f_strings_but_not_prose() -> None:
    source = '''
"""Module doc naming PLC.LIC1.SP."""
a = "PLC.LIC1.SP"
b = f"Plant.{name}.Leak"
c = f"PLC.IO.LT{t[1:]}.PV"
d = "PLC.%s.SetGains"
e = "Supervisor."
f = f"Supervisor's output [{unit}]"
g = "Plant"
def h():
    """PLC.LIC1.Mode in a docstring."""
'''
    found = [text for _, text in path_literals(source)]
    assert found == ["PLC.LIC1.SP", "f'Plant.{name}.Leak'", "f'PLC.IO.LT{t[1:]}.PV'", "PLC.%s.SetGains"]


def _literals_by_file() -> dict[str, list[tuple[int, str]]]:
    out = {}
    for file in sorted(SRC.rglob("*.py")):
        rel = file.relative_to(SRC).as_posix()
        if rel.startswith(TEST_SUPPORT):
            continue
        if found := path_literals(file.read_text(encoding="utf-8")):
            out[rel] = found
    return out


def test_no_node_path_is_spelled_outside_the_contract() -> None:
    by_file = _literals_by_file()
    stray = {f: lits for f, lits in by_file.items() if f not in CONTRACT}
    assert not stray, "node paths spelled outside tanklab.paths (use its builders): " + "; ".join(
        f"{f}:{line} {text}" for f, lits in stray.items() for line, text in lits
    )
    assert set(by_file) == CONTRACT  # the scanner still sees the contract's own paths


def test_the_builders_spell_the_contract_paths() -> None:
    assert paths.plant.tank("T2").leak == "Plant.T2.Leak"
    assert paths.plant.lt("T3").fault_value == "Plant.LT3.FaultValue"
    assert paths.plant.pump("P1").command == "Plant.P1.Command"
    assert paths.plant.valve_opening("V13") == "Plant.V13.Opening"
    assert paths.plant.balance("Error") == "Plant.Balance.Error"
    assert paths.plc.loop("LIC2").sp_high == "PLC.LIC2.SPHigh"
    assert paths.plc.loop("LIC1").gains == ("PLC.LIC1.Kp", "PLC.LIC1.Ki", "PLC.LIC1.Kd")
    assert paths.plc.io("T1").good == "PLC.IO.LT1.Good"
    assert paths.plc.interlock("T1") == "PLC.Interlock.T1HH"
    assert paths.plc.alarm("T2", "L") == "PLC.Alarms.T2L"
    assert paths.plc.heartbeat == "PLC.Supervisor.Heartbeat"
    assert paths.supervisor.rls("LIC1").noise_std == "Supervisor.RLS.LIC1.NoiseStd"
    assert paths.supervisor.disturbance == "Supervisor.Estimator.Disturbance"
    assert paths.plant.transmitter("LT2") is paths.plant.lt("T2")
    assert paths.plant.lt("T2").name == "LT2"
    assert paths.PROBE_PATHS == {
        "plant": "Plant.Sim.Time",
        "plc": "PLC.Status.Scan",
        "supervisor": "Supervisor.Mode",
        "historian": "Historian.Status.StoreKind",
    }
    assert paths.historian.tier("plc").gaps == "Historian.Status.PLC.Gaps"


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_the_alarm_and_interlock_prefixes_cover_exactly_those_nodes(config: Path) -> None:
    site = load_site(config)
    if site.plc is None:
        return
    by_path = {t.path: t for t in plc_tags(site)}
    alarms = {p for p in by_path if p.startswith(paths.plc.alarms_prefix)}
    interlocks = {p for p in by_path if p.startswith(paths.plc.interlocks_prefix)}
    assert paths.plc.io_fault in alarms and paths.plc.supervisor_lost in alarms
    for tank in site.tank_names:
        assert {paths.plc.alarm(tank, k) for k in ("H", "L", "HH")} <= alarms
    for loop in site.loop_names:
        assert paths.plc.pv_bad_alarm(loop) in alarms
    assert paths.plc.interlock_reset in interlocks
    assert all(p.split(".")[1] == "Alarms" for p in alarms)
    assert all(p.split(".")[1] == "Interlock" for p in interlocks)


# ---- one handler per writable tag ---------------------------------------------------------


def _assert_one_handler_each(tags: list[Tag], writes: HandlerTable[Any], calls: HandlerTable[Any]) -> None:
    assert set(writes) == writable_variables(tags)
    assert set(calls) == methods_of(tags)
    assert writable_variables(tags) | methods_of(tags) == {t.path for t in tags if t.writable}
    check_handlers(tags, writes, calls)


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_every_writable_tag_has_exactly_one_handler_in_its_server(config: Path) -> None:
    site = load_site(config)
    security = cast(Any, None)  # not started: only the handler tables are looked at
    plant = PlantServer(site, PlantSimulator(site.plant), "127.0.0.1", 0, security)
    _assert_one_handler_each(plant_tags(site), plant.write_handlers(), plant.method_handlers())
    if site.plc is None:
        return
    plc = PlcServer(site, PlcProgram(site), "127.0.0.1", 0, security)
    _assert_one_handler_each(plc_tags(site), plc.write_handlers(), plc.method_handlers())
    if site.supervisor is None:
        return
    sup = SupervisorServer(site, SupervisorCore(site), "127.0.0.1", 0, security)
    _assert_one_handler_each(supervisor_tags(site), sup.write_handlers(), HandlerTable())


def test_a_second_handler_for_a_tag_is_refused() -> None:
    table: HandlerTable[int] = HandlerTable()
    table.on("PLC.LIC1.SP", 1)
    with pytest.raises(ValueError, match=r"second handler for PLC\.LIC1\.SP"):
        table.on("PLC.LIC1.SP", 2)
    assert dict(table) == {"PLC.LIC1.SP": 1}


def test_a_missing_or_stray_handler_is_named() -> None:
    site = load_site(ROOT / "configs/single_tank_short_sim.yaml")
    tags = plc_tags(site)
    writes = {p: None for p in writable_variables(tags) if p != paths.plc.loop("LIC1").remote_mv}
    writes[paths.plc.loop("LIC1").pv] = None
    with pytest.raises(ValueError) as err:
        check_handlers(tags, writes, dict.fromkeys(methods_of(tags)))
    assert "no write handler for PLC.LIC1.RemoteMV" in str(err.value)
    assert "not make writable: PLC.LIC1.PV" in str(err.value)


def test_the_in_process_port_writes_through_the_same_handlers() -> None:
    site = load_site(ROOT / "configs/single_tank_short_sim.yaml")
    program = PlcProgram(site)
    loop = paths.plc.loop("LIC1")
    assert set(program_writes(program)) == writable_variables(plc_tags(site))
    assert apply_write(program, loop.sp, 0.2) is True
    assert status_values(program.status())[loop.sp] == 0.2
    assert apply_write(program, loop.pv, 0.2) is False  # read-only: no handler
    with pytest.raises(ValueError):
        apply_write(program, loop.sp, 1e6)  # the program's own range check
    assert status_values(program.status())[loop.sp] == 0.2
