"""``tankctl alarms`` / ``ack`` / ``shelve``: durations, rows and the table, without a server."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from types import SimpleNamespace

import pytest
from asyncua import ua
from rich.console import Console
from typer.testing import CliRunner

from helpers import ROOT
from tankctl.cli import app
from tankctl.ops.alarm_summary import summary_json, summary_line, summary_paths, unacknowledged_line
from tankctl.ops.alarms import (
    LIMIT_FIELD,
    STATE_FIELDS,
    TierAlarms,
    child,
    condition_rows,
    find,
    known,
    parse_duration_ms,
    read_paths,
    render_rows,
)
from tankctl.ops.errors import UsageError
from tankctl.up_board import Board
from tanklab.alarms.definitions import plc_alarms, supervisor_alarms
from tanklab.alarms.model import ConditionKind
from tanklab.config import load_site

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
DEFS = plc_alarms(SITE)


@pytest.mark.parametrize(
    ("text", "ms"),
    [
        ("15m", 900_000.0),
        ("900s", 900_000.0),
        ("1h", 3_600_000.0),
        ("1h30m", 5_400_000.0),
        ("500ms", 500.0),
        ("90", 90_000.0),
        (" 2M ", 120_000.0),
        ("1.5s", 1500.0),
        ("1d", 86_400_000.0),
    ],
)
def test_durations_are_milliseconds(text: str, ms: float) -> None:
    assert parse_duration_ms(text) == ms


@pytest.mark.parametrize("text", ["", "m", "15 minutes", "-5m", "0s", "1x", "nan", "1h-5m", "s15"])
def test_bad_durations_are_usage_errors(text: str) -> None:
    with pytest.raises(UsageError):
        parse_duration_ms(text)


def test_one_read_covers_every_condition_and_only_level_alarms_have_a_limit() -> None:
    nodes = read_paths(DEFS)
    assert len(nodes) == len(set(nodes))
    for d in DEFS:
        has_limit = child(d.name, LIMIT_FIELD) in nodes
        assert has_limit == (d.kind == ConditionKind.EXCLUSIVE_LEVEL)
        assert all(child(d.name, f) in nodes for f in STATE_FIELDS)
    assert child("T1Level", "AckedState/Id") == "PLC.Conditions.T1Level.AckedState.Id"


def _values(name: str, *, active: bool, acked: bool, retain: bool, **extra: object) -> dict[str, object]:
    fields = {
        "Severity": 700,
        "Message": ua.LocalizedText("T1 level low"),
        "Time": datetime(2026, 12, 2, 7, 30, 5, tzinfo=UTC),
        "Retain": retain,
        "EnabledState/Id": True,
        "ActiveState/Id": active,
        "AckedState/Id": acked,
        "ShelvingState/CurrentState": ua.LocalizedText("Unshelved"),
        LIMIT_FIELD: ua.LocalizedText("Low"),
        **extra,
    }
    return {child(name, f): v for f, v in fields.items()}


def test_standing_rows_their_states_and_every_row_with_all() -> None:
    values = {
        **_values("T1Level", active=True, acked=False, retain=True),
        **_values(
            "T2Level",
            active=False,
            acked=True,
            retain=False,
            **{"ShelvingState/CurrentState": ua.LocalizedText("TimedShelved")},
        ),
        **_values("IoFault", active=False, acked=False, retain=True, **{"EnabledState/Id": False}),
    }
    standing = condition_rows(DEFS, values)
    assert [r.name for r in standing] == ["T1Level", "IoFault"]
    t1, io = standing
    assert (t1.state, t1.limit, t1.priority, t1.since) == (
        "ACTIVE UNACK",
        "Low",
        "HIGH",
        "2026-12-02T07:30:05Z",
    )
    assert io.state == "RTN UNACK DISABLED" and io.limit is None
    every = {r.name: r for r in condition_rows(DEFS, values, every=True)}
    assert len(every) == len(DEFS)
    assert every["T2Level"].state == "RTN ACK SHELVED"
    # A condition whose nodes all read Bad (None) shows as unknown, not as standing.
    assert every["T3Level"].severity is None and not every["T3Level"].standing
    assert t1.as_json()["state"] == "ACTIVE UNACK" and t1.as_json()["acked"] is False


def test_the_table_has_a_header_and_one_line_per_row() -> None:
    rows = condition_rows(DEFS, _values("T1Level", active=True, acked=False, retain=True))
    lines = render_rows(rows).splitlines()
    assert lines[0].split() == ["TIER", "NAME", "PRIORITY", "STATE", "LIMIT", "SINCE", "MESSAGE"]
    assert lines[1].split() == [
        "plc",
        "T1Level",
        "HIGH",
        "(700)",
        "ACTIVE",
        "UNACK",
        "Low",
        "2026-12-02T07:30:05Z",
        "T1",
        "level",
        "low",
    ]
    assert render_rows([]) == "no standing alarms"


def test_an_unknown_name_lists_the_known_ones() -> None:
    assert known(DEFS, "t1level").name == "T1Level"
    with pytest.raises(UsageError, match=r"unknown alarm 'T9Level' \(the PLC has T1Level, .*IoFault"):
        known(DEFS, "T9Level")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["shelve", "T1Level"], "give one of --for DURATION and --once"),
        (["shelve", "T1Level", "--once", "--for", "5m"], "give one of --for DURATION and --once"),
        (["shelve", "T1Level", "--for", "soon"], "a duration is like 15m"),
    ],
)
def test_shelve_checks_its_options_before_connecting(argv: list[str], message: str) -> None:
    r = CliRunner().invoke(app, [*argv, "--base-port", "1"])
    assert r.exit_code == 2
    assert message in r.output


def test_an_unknown_alarm_is_exit_2_with_the_known_names_before_connecting() -> None:
    config = str(ROOT / "configs/three_tank_energies_sim.yaml")
    r = CliRunner().invoke(app, ["ack", "T9Level", "--config", config, "--base-port", "1"])
    assert r.exit_code == 2
    assert "unknown alarm 'T9Level' (the PLC has T1Level" in r.output


# ---- both tiers (the supervisor's conditions too) ----------------------------------------------

SUP = supervisor_alarms(SITE)
TIERS = [TierAlarms("plc", DEFS), TierAlarms("supervisor", SUP)]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_condition_names_are_unique_across_the_tiers_of_every_shipped_site(path: Path) -> None:
    site = load_site(path)
    plc = {d.name.lower() for d in plc_alarms(site)} if site.plc is not None else set()
    sup = {d.name.lower() for d in supervisor_alarms(site)} if site.supervisor is not None else set()
    assert not plc & sup


def test_a_name_finds_its_tier_and_a_tier_prefix_looks_there_only() -> None:
    tier, d = find(TIERS, "plclinklost")
    assert (tier.tier, d.name) == ("supervisor", "PlcLinkLost")
    assert find(TIERS, "T1Level")[0].tier == "plc"
    assert find(TIERS, "supervisor/MpcFailing")[1].name == "MpcFailing"
    assert find(TIERS, " PLC / IoFault ")[0].tier == "plc"
    with pytest.raises(UsageError, match=r"unknown alarm 'plc/MpcFailing' \(the PLC has T1Level"):
        find(TIERS, "plc/MpcFailing")
    with pytest.raises(
        UsageError, match=r"unknown tier 'plant' in 'plant/T1Level' \(alarms are on plc, supervisor\)"
    ):
        find(TIERS, "plant/T1Level")
    with pytest.raises(UsageError, match=r"\(the PLC has T1Level, .*; the supervisor has MpcFailing, "):
        find(TIERS, "T9Level")


def test_a_name_on_two_tiers_is_never_guessed() -> None:
    twice = [TierAlarms("plc", DEFS), TierAlarms("supervisor", DEFS)]
    with pytest.raises(UsageError, match=r"on more than one tier: give plc/IoFault or supervisor/IoFault"):
        find(twice, "IoFault")
    assert find(twice, "supervisor/IoFault")[0].tier == "supervisor"


def test_supervisor_rows_read_its_own_nodes_and_carry_the_tier() -> None:
    nodes = read_paths(SUP, "supervisor")
    assert child("PlcLinkLost", "AckedState/Id", "supervisor") in nodes
    assert all(n.startswith("Supervisor.Conditions.") for n in nodes)
    assert not any(n.endswith(LIMIT_FIELD.replace("/", ".")) for n in nodes)  # discrete alarms only
    values = {
        child("PlcLinkLost", f, "supervisor"): v
        for f, v in {
            "Severity": 700,
            "Message": ua.LocalizedText("PLC link lost"),
            "Retain": True,
            "ActiveState/Id": True,
            "AckedState/Id": True,
        }.items()
    }
    (row,) = condition_rows(SUP, values, tier="supervisor")
    assert (row.tier, row.name, row.state, row.priority) == (
        "supervisor",
        "PlcLinkLost",
        "ACTIVE ACK",
        "HIGH",
    )
    assert row.as_json()["tier"] == "supervisor"
    assert render_rows([row]).splitlines()[1].split()[:2] == ["supervisor", "PlcLinkLost"]


def test_an_unknown_alarm_names_both_tiers_before_connecting() -> None:
    config = str(ROOT / "configs/three_tank_energies_sim.yaml")
    r = CliRunner().invoke(app, ["unshelve", "Nope", "--config", config, "--base-port", "1"])
    assert r.exit_code == 2
    assert "; the supervisor has MpcFailing, AdaptationUnhealthy, PlcLinkLost)" in r.output


# ---- the alarm summary of status and the board --------------------------------------------


def _summary_values(tier: str, *values: int | bool) -> dict[str, int | bool]:
    root = "PLC" if tier == "plc" else "Supervisor"
    items = ("Active", "Unacknowledged", "Shelved", "Suppressed", "Disabled", "RatePer10Min")
    items += ("PeakRatePer10Min", "Flood")
    return {f"{root}.AlarmSummary.{i}": v for i, v in zip(items, values, strict=True)}


def test_the_summary_json_and_its_line() -> None:
    doc = summary_json("plc", _summary_values("plc", 2, 1, 0, 0, 0, 3, 4, False))
    assert doc == {
        "active": 2,
        "unacknowledged": 1,
        "shelved": 0,
        "suppressed": 0,
        "disabled": 0,
        "rate_per_10min": 3,
        "peak_rate_per_10min": 4,
        "flood": False,
    }
    assert (
        summary_line("plc", doc)
        == "PLC alarms: 2 active, 1 unacknowledged, 0 shelved, rate 3/10 min (peak 4)"
    )
    flood = summary_json("supervisor", _summary_values("supervisor", 12, 12, 1, 2, 1, 11, 11, True))
    assert summary_line("supervisor", flood) == (
        "supervisor alarms: 12 active, 12 unacknowledged, 1 shelved, 2 suppressed, 1 disabled, "
        "rate 11/10 min (peak 11), FLOOD"
    )
    assert summary_line("plc", summary_json("plc", {})) == "PLC alarms: no summary"
    assert summary_paths("plc") == list(_summary_values("plc", 0, 0, 0, 0, 0, 0, 0, False))


def test_the_boards_unacknowledged_line() -> None:
    assert (
        unacknowledged_line({"plc": {"unacknowledged": 1, "flood": False}}) == "unacknowledged alarms: PLC 1"
    )
    both = {
        "plc": {"unacknowledged": 11, "flood": True},
        "supervisor": {"unacknowledged": None, "flood": None},
    }
    assert unacknowledged_line(both) == "unacknowledged alarms: PLC 11 FLOOD, supervisor ?"


def test_the_up_board_renders_the_unacknowledged_line_from_the_summary_nodes() -> None:
    tier = SimpleNamespace(log_path="x.log", url="opc.tcp://127.0.0.1:1/x")
    tiers = {"plant": tier, "plc": tier, "supervisor": tier}
    local = SimpleNamespace(site=SITE, clock="realtime", speed=1.0, tiers=tiers, link=lambda *a: None)
    board = Board(local)  # type: ignore[arg-type]
    assert "PLC.AlarmSummary.Unacknowledged" in board.plc_paths  # read with the board's one Read
    assert "Supervisor.AlarmSummary.Flood" in board.sup_paths
    board.values = _summary_values("plc", 3, 2, 0, 0, 0, 11, 11, True)
    board.values |= _summary_values("supervisor", 0, 0, 0, 0, 0, 0, 0, False)
    console = Console(width=120, record=True)
    console.print(board.render([]))
    assert "unacknowledged alarms: PLC 2 FLOOD, supervisor 0" in console.export_text().splitlines()
