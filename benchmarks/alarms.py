"""The alarm-flood benchmark (issue 15, "no regression of the scan"): many conditions raised in one
PLC scan and one client acknowledging them all, through real plant and PLC processes at a 1 s scan.

**The site.** The issue asks for 50 alarms raised in one scan. Tank, pump and loop numbers go
to 99 (``T1``..``T99``, decision 0045), so :func:`flood_site` generates a 25-tank site from the
shipped Energies one (25 copies of its T1 loop: pump P{i} into T{i}, outlet valve V{i}0 to the
drain, LIC1's PID and T1's high-high interlock on every tank, the tanks at the equilibrium of
0.4 m, no supervisor; 77 conditions on its PLC: 25 levels, 25 PvBad, 25 trips, IoFault,
SupervisorLost). One plant event, a common-mode transmitter fault (one Write request setting
``Plant.LT{i}.Fault = BIAS`` on all 25 transmitters, the bias :data:`BIAS_M` written
beforehand), puts every reading above the 0.58 m trip in the same scan: 25 ``T{i}Level``
(HighHigh) and 25 ``T{i}Trip`` conditions, :data:`N_CONDITIONS` = 50, active in one scan
(:func:`flood_conditions`; a unit test checks it on the PLC program).

**A round** (:func:`one_round`), on the PLC at speed 1 (scan period 1 s of wall time):

1. quiet scans (the baseline scan duration), then the fault Write on the plant;
2. the 50 activation events arrive at a client subscribed to the Server object (asyncua, the
   test support's event filter, 100 ms publishing interval); counted, each one's arrival time
   (``time.time()`` in its handler) against its ``Time`` (the wall stamp of the scan that raised
   it, same machine clock);
3. one client acknowledges all 50 with the EventIds just received: in one Call request of 50
   method calls, or (alternate rounds) in 50 Call requests one after the other; the 50
   acknowledged events are counted and timed from the first request sent; the PLC's alarm
   summary (``PLC.AlarmSummary.RatePer10Min``, ``Flood``, ``Unacknowledged``) is read once the
   activation is counted and one scan period after the last acknowledgement;
4. the fault is cleared (one Write): the 25 level conditions return to normal; the interlock is
   reset (``PLC.Interlock.Reset``): the 25 latched trips return to normal; the trips, configured
   for confirmation, are confirmed in one Call (25 events).

Meanwhile a third session reads ``PLC.Scan``, ``PLC.LastScanDuration``, ``PLC.Overruns`` and the
25 ``PLC.Alarms.T{i}HH`` every :data:`POLL_S`; the last read of each scan gives its duration (the
work of the scan, field I/O and publishing included) and the booleans it published, so the
activation scan is the first scan after the Write with the HH booleans set. The PLC's CPU time
(all its threads, ``/proc/<pid>/task/*/schedstat``, nanoseconds) is taken around the activation
and the acknowledgement. The overrun counter is read before the first and after the last round;
the PLC's own stop line gives the scan count, overruns and start lateness over the whole run.
Every process is stopped on every path (``Stack.down``) and the stack's ports are checked for
tankctl processes left afterwards.
"""

from __future__ import annotations

import asyncio
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import yaml
from asyncua import Client, ua

from benchmarks.common import ENERGIES, speed_reference
from benchmarks.stack import Lateness, parse_lateness
from plant_sim.linearize import operating_point
from plant_sim.models import TankNetwork, default_inputs
from tanklab import paths
from tanklab.alarms import names
from tanklab.config import SiteConfig
from tanklab.enums import SensorFault
from tanklab_testing.condition_events import event_filter
from tanklab_testing.logins import Logins, provision, session
from tanklab_testing.procs import free_base_port, tankctl_pids_on
from tanklab_testing.stack import Stack

N_TANKS = 25
"""Tanks of the flood site: each raises its level alarm (HighHigh) and its trip, 50 in all."""
BIAS_M = 0.45
"""The common-mode transmitter bias [m]: any reading from :data:`READY_M` up reads above the
0.58 m trip (0.4 m reads 0.62 m, the range's top)."""
LEVEL_M = 0.4
"""Every tank's equilibrium level [m] (LIC1's setpoint)."""
READY_M = 0.15
"""A round starts once every reading is above this level [m] (0.15 + BIAS_M = 0.60 m > 0.58 m).

The trip forces the pumps off from the activation to the reset (a few seconds, the tanks drain
at about 4.5 mm/s at 0.4 m), and LIC1's PID, tracking the forced command, rebuilds its integral
slowly (Ki 5.32e-6 per m s): the levels fall a few cm per round and recover over minutes, so the
bias is large enough for any level a run reaches rather than waiting for the setpoint."""
ROUNDS = 10
"""Rounds in a full run: acknowledging in one Call and in separate Calls alternate."""
QUIET_SCANS = 3
"""Ordinary scans before each round's fault (the baseline scan duration)."""
POLL_S = 0.2
"""Period of the scan-duration reads [s]."""
EVENT_TIMEOUT_S = 20.0
READY_TIMEOUT_S = 90.0
FIELDS = ("EventId", "Time", "Message", "ActiveState/Id", "AckedState/Id", "ConfirmedState/Id")
ONE_CALL = "one Call"
SEPARATE = "separate Calls"
ACK = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
CONFIRM = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Confirm)


# ----------------------------------------------------------------------------------------------
# the site (pure)
# ----------------------------------------------------------------------------------------------
def flood_site(n_tanks: int = N_TANKS) -> dict[str, Any]:
    """The flood site as YAML data: ``n_tanks`` copies of the Energies site's T1 loop (tank, pump,
    outlet valve to the drain, LIC1's PID, T1's interlock), at the equilibrium of
    :data:`LEVEL_M`, without a supervisor."""
    base = yaml.safe_load(ENERGIES.read_text(encoding="utf-8"))
    tank, pump = base["plant"]["tanks"][0], base["plant"]["pumps"][0]
    loop, interlock = base["plc"]["loops"][0], base["plc"]["interlocks"][0]
    valve = base["plant"]["valves"][0]  # V13: mu 0.5 through 5e-5 m^2
    ids = range(1, n_tanks + 1)
    plant = {
        **base["plant"],
        "description": f"{n_tanks} copies of the Energies T1 loop, each draining to the floor.",
        "tanks": [{**tank, "name": f"T{i}", "initial_level_m": LEVEL_M} for i in ids],
        "valves": [
            {"name": f"V{i}0", "upstream": f"T{i}", "mu": valve["mu"], "area_m2": valve["area_m2"]}
            for i in ids
        ],
        "pumps": [{**pump, "name": f"P{i}", "feeds": f"T{i}"} for i in ids],
        "operating_point": {"levels_m": [LEVEL_M] * n_tanks, "flows_m3_s": None},
    }
    plc = {
        **base["plc"],
        "loops": [{**loop, "name": f"LIC{i}", "pv": f"LT{i}", "actuator": f"P{i}"} for i in ids],
        "interlocks": [{**interlock, "tank": f"T{i}"} for i in ids],
    }
    data: dict[str, Any] = {
        "name": f"alarm_flood_{n_tanks}",
        "description": "Generated by benchmarks/alarms.py: the alarm-flood benchmark's site.",
        "plant": plant,
        "plc": plc,
    }
    site = SiteConfig.model_validate(data)
    net = TankNetwork.from_config(site.plant)
    op = operating_point(net, site.plant, default_inputs(net, site.plant))
    for p, command in zip(plant["pumps"], op.commands, strict=True):
        p["initial_command"] = float(command)
    return data


def flood_conditions(n_tanks: int = N_TANKS) -> list[str]:
    """The conditions the fault makes active in one scan: every tank's level alarm and trip."""
    tanks = [f"T{i}" for i in range(1, n_tanks + 1)]
    return [names.level(t) for t in tanks] + [names.trip(t) for t in tanks]


N_CONDITIONS = len(flood_conditions())


# ----------------------------------------------------------------------------------------------
# what one run records
# ----------------------------------------------------------------------------------------------
@dataclass
class Round:
    """One flood: activation, acknowledge-all, return, reset and confirm."""

    index: int
    mode: str
    """How the acknowledgements went: :data:`ONE_CALL` or :data:`SEPARATE`."""
    conditions: int = N_CONDITIONS
    activation_events: int = 0
    """Activation events received (of ``conditions``)."""
    activation_times: int = 0
    """Distinct ``Time`` stamps among them: 1 = all raised by one scan."""
    activation_latency_s: float = float("nan")
    """From the raising scan's wall stamp to the last activation event's arrival [s]."""
    activation_scan_s: float = float("nan")
    """``PLC.LastScanDuration`` of the activation scan [s]."""
    activation_scan_alarms: int = 0
    """``PLC.Alarms.T{i}HH`` set in the activation scan (of the tanks)."""
    activation_cpu_s: float = float("nan")
    """PLC CPU time from the fault Write to the last activation event [s]."""
    baseline_scan_s: float = float("nan")
    """Median ``PLC.LastScanDuration`` of the quiet scans before the fault [s]."""
    ack_call_s: float = float("nan")
    """From the first Call request sent to the last answer [s]."""
    ack_good: int = 0
    """Acknowledge calls answered Good."""
    ack_events: int = 0
    ack_latency_s: float = float("nan")
    """From the first Call request sent to the last acknowledged event's arrival [s]."""
    ack_scan_s: float = float("nan")
    """Longest ``PLC.LastScanDuration`` of the scans first seen from the call to one scan period
    after the last acknowledged event [s]."""
    ack_cpu_s: float = float("nan")
    """PLC CPU time from the first Call request to the last acknowledged event [s]."""
    summary_rate: int = -1
    """``PLC.AlarmSummary.RatePer10Min`` once the activation is counted (-1: not read): this
    round's conditions plus the earlier rounds' still in the 600 s window."""
    summary_flood: bool | None = None
    """``PLC.AlarmSummary.Flood`` then (a round raises more than 10: true)."""
    summary_unacked_after_ack: int = -1
    """``PLC.AlarmSummary.Unacknowledged`` one scan period after the last acknowledged event."""
    return_events: int = 0
    """Returns to normal received (levels after the fault is cleared, trips after the reset)."""
    confirm_events: int = 0
    overruns_before: int = 0
    overruns_after: int = 0
    wall_s: float = float("nan")
    error: str = ""


@dataclass
class AlarmsResult:
    rounds: list[Round] = field(default_factory=list)
    site_conditions: int = 0
    """Conditions on the flood site's PLC."""
    scan_period_s: float = 1.0
    speed_ms: float = float("nan")
    """Machine speed reference at the section's start [ms] (:func:`benchmarks.common.speed_reference`)."""
    overruns_start: int | None = None
    overruns_end: int | None = None
    """``PLC.Overruns`` before the first round and after the last."""
    plc: Lateness | None = None
    """The PLC's stop line: scans, overruns, start lateness over the whole run."""
    left: list[int] = field(default_factory=list)
    """tankctl processes still on the stack's ports after it was stopped."""
    startup_s: float = float("nan")
    wall_s: float = float("nan")
    errors: list[str] = field(default_factory=list)


# ----------------------------------------------------------------------------------------------
# measuring
# ----------------------------------------------------------------------------------------------
def cpu_ns(pid: int) -> int:
    """CPU time of every thread of process ``pid`` [ns] (``/proc/<pid>/task/*/schedstat``); 0 if gone."""
    total = 0
    for stat in Path(f"/proc/{pid}/task").glob("*/schedstat"):
        try:
            total += int(stat.read_text().split()[0])
        except (OSError, ValueError, IndexError):
            continue
    return total


class Arrivals:
    """The subscription handler: each event's selected fields, its ConditionId (``NodeId``) and
    its arrival (``_at``, ``time.time()``), in arrival order."""

    def __init__(self) -> None:
        self.items: list[dict[str, Any]] = []

    def event_notification(self, event: Any) -> None:
        item = {k: v.Value for k, v in event.get_event_props_as_fields_dict().items()}
        item["_at"] = time.time()
        self.items.append(item)


def epoch_s(stamp: datetime) -> float:
    """An event's ``Time`` (UTC, naive as asyncua decodes it) as seconds since the epoch."""
    return (stamp if stamp.tzinfo is not None else stamp.replace(tzinfo=UTC)).timestamp()


@dataclass
class ScanSeen:
    first_seen: float
    duration_s: float
    overruns: int
    hh: int


class Poller:
    """Reads the PLC's scan counter, last scan duration, overrun counter and HH booleans every
    :data:`POLL_S`; per scan the last read wins (it comes after the scan's own publishing)."""

    def __init__(self, client: Client, idx: int, tanks: Sequence[str]) -> None:
        plc = paths.plc
        ids = [plc.scan, plc.last_scan_duration, plc.overruns, *(plc.alarm(t, "HH") for t in tanks)]
        self.nodes = [client.get_node(ua.NodeId(p, idx)) for p in ids]
        self.client = client
        self.scans: dict[int, ScanSeen] = {}
        self.task: asyncio.Task[None] | None = None

    async def read(self) -> tuple[int, ScanSeen]:
        values = await self.client.read_values(self.nodes)
        scan = int(values[0])
        seen = self.scans.get(scan)
        first = seen.first_seen if seen is not None else time.time()
        self.scans[scan] = ScanSeen(first, float(values[1]), int(values[2]), sum(bool(v) for v in values[3:]))
        return scan, self.scans[scan]

    async def _run(self) -> None:
        while True:
            await self.read()
            await asyncio.sleep(POLL_S)

    def start(self) -> None:
        self.task = asyncio.create_task(self._run())

    async def stop(self) -> None:
        if self.task is not None:
            self.task.cancel()
            await asyncio.gather(self.task, return_exceptions=True)


async def wait_for(what: str, cond: Callable[[], bool], timeout_s: float = EVENT_TIMEOUT_S) -> None:
    """Poll ``cond`` every 5 ms until true; a RuntimeError naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        await asyncio.sleep(0.005)


class Bench:
    """The stack's sessions and the conditions' ids."""

    def __init__(self, stack: Stack, logins: Logins, tanks: Sequence[str]) -> None:
        self.stack = stack
        self.logins = logins
        self.tanks = list(tanks)
        self.events = Arrivals()
        self.names = flood_conditions(len(tanks))

    def cids(self, idx: int) -> dict[ua.NodeId, str]:
        return {ua.NodeId(paths.condition("plc", n), idx): n for n in self.names}

    def since(self, start: int, cids: dict[ua.NodeId, str], key: str, value: bool) -> list[dict[str, Any]]:
        """Events of ``cids`` received after index ``start`` with field ``key`` == ``value``."""
        return [e for e in self.events.items[start:] if e.get("NodeId") in cids and e.get(key) is value]

    async def wait_all(
        self, what: str, start: int, cids: dict[ua.NodeId, str], key: str, value: bool
    ) -> list[dict[str, Any]]:
        """Wait until every condition of ``cids`` has an event after ``start`` with ``key`` ==
        ``value``; those events."""

        def done() -> bool:
            return len({e["NodeId"] for e in self.since(start, cids, key, value)}) >= len(cids)

        await wait_for(what, done)
        return self.since(start, cids, key, value)

    def latest(self, cids: dict[ua.NodeId, str]) -> dict[ua.NodeId, bytes]:
        """The latest EventId of each condition received so far."""
        out: dict[ua.NodeId, bytes] = {}
        for e in self.events.items:
            if e.get("NodeId") in cids:
                out[e["NodeId"]] = e["EventId"]
        return out


async def _call(client: Client, requests: list[ua.CallMethodRequest]) -> list[str]:
    results = await client.uaclient.call(requests)
    return [str(r.StatusCode.name) for r in results]


def _comment_args(event_id: bytes, comment: str) -> list[ua.Variant]:
    return [
        ua.Variant(event_id, ua.VariantType.ByteString),
        ua.Variant(ua.LocalizedText(comment), ua.VariantType.LocalizedText),
    ]


async def one_round(
    bench: Bench,
    index: int,
    mode: str,
    *,
    plant: Client,
    pidx: int,
    op: Client,
    idx: int,
    poller: Poller,
    plc_pid: int,
    period_s: float,
) -> Round:
    """One flood (module docstring: a round); raises on a timeout (the caller records it)."""
    rnd = Round(index, mode, conditions=len(bench.names))
    cids = bench.cids(idx)
    levels = {c: n for c, n in cids.items() if n.endswith("Level")}
    trips = {c: n for c, n in cids.items() if n.endswith("Trip")}
    pv_nodes = [op.get_node(ua.NodeId(paths.plc.loop(f"LIC{t[1:]}").pv, idx)) for t in bench.tanks]

    async def ready() -> bool:
        return min(float(v) for v in await op.read_values(pv_nodes)) >= READY_M

    deadline = time.monotonic() + READY_TIMEOUT_S
    while not await ready():
        if time.monotonic() > deadline:
            raise RuntimeError(f"levels not back above {READY_M} m within {READY_TIMEOUT_S:.0f} s")
        await asyncio.sleep(0.5)
    scan0, _ = await poller.read()
    await wait_for(f"{QUIET_SCANS} quiet scans", lambda: max(poller.scans) >= scan0 + QUIET_SCANS + 1, 30.0)
    quiet = [poller.scans[s].duration_s for s in range(scan0 + 1, scan0 + QUIET_SCANS + 1)]
    rnd.baseline_scan_s = statistics.median(quiet) if quiet else float("nan")
    last_scan, seen = await poller.read()
    rnd.overruns_before = seen.overruns
    started = time.perf_counter()

    # 1-2: the fault, the activation events
    start = len(bench.events.items)
    fault = [plant.get_node(ua.NodeId(paths.plant.lt(t).fault, pidx)) for t in bench.tanks]
    cpu0 = cpu_ns(plc_pid)
    await plant.write_values(fault, [ua.Variant(int(SensorFault.BIAS), ua.VariantType.Int32)] * len(fault))
    active = await bench.wait_all("the activation events", start, cids, "ActiveState/Id", True)
    rnd.activation_cpu_s = (cpu_ns(plc_pid) - cpu0) * 1e-9
    rnd.activation_events = len({e["NodeId"] for e in active})
    stamps = {e["Time"] for e in active}
    rnd.activation_times = len(stamps)
    raised = min(epoch_s(s) for s in stamps)
    rnd.activation_latency_s = max(e["_at"] for e in active) - raised
    # the activation scan: the first scan after the Write that published the HH booleans
    await wait_for("the activation scan's duration", lambda: max(poller.scans) > last_scan + 1, 10.0)
    after = sorted(s for s in poller.scans if s > last_scan and poller.scans[s].hh > 0)
    if after:
        # its duration is the last read of that scan: wait until the next scan has been seen
        await wait_for("the scan after the activation", lambda: max(poller.scans) > after[0], 10.0)
        rnd.activation_scan_s = poller.scans[after[0]].duration_s
        rnd.activation_scan_alarms = poller.scans[after[0]].hh

    # the alarm summary: the flood counted (its Unacknowledged covers the round's conditions)
    summary = paths.alarm_summary_paths("plc")
    summary_nodes = [
        op.get_node(ua.NodeId(summary[k], idx)) for k in ("RatePer10Min", "Flood", "Unacknowledged")
    ]
    deadline = time.monotonic() + EVENT_TIMEOUT_S
    while True:
        rate, flood, unacked = await op.read_values(summary_nodes)
        if unacked >= len(cids) or time.monotonic() > deadline:
            break
        await asyncio.sleep(0.05)
    rnd.summary_rate, rnd.summary_flood = int(rate), bool(flood)

    # 3: acknowledge them all, with the EventIds just received
    ids = bench.latest(cids)
    requests = [
        ua.CallMethodRequest(ObjectId=c, MethodId=ACK, InputArguments=_comment_args(ids[c], "flood seen"))
        for c in cids
    ]
    start = len(bench.events.items)
    scan_at_call, _ = await poller.read()
    cpu0 = cpu_ns(plc_pid)
    t0 = time.time()
    if mode == ONE_CALL:
        statuses = await _call(op, requests)
    else:
        statuses = [(await _call(op, [r]))[0] for r in requests]
    rnd.ack_call_s = time.time() - t0
    rnd.ack_good = statuses.count("Good")
    acked = await bench.wait_all("the acknowledged events", start, cids, "AckedState/Id", True)
    rnd.ack_cpu_s = (cpu_ns(plc_pid) - cpu0) * 1e-9
    rnd.ack_events = len({e["NodeId"] for e in acked})
    last_ack = max(e["_at"] for e in acked)
    rnd.ack_latency_s = last_ack - t0
    await wait_for("a scan after the acknowledgements", lambda: time.time() > last_ack + period_s, 10.0)
    await poller.read()
    rnd.summary_unacked_after_ack = int(await summary_nodes[2].read_value())
    until = last_ack + period_s
    during = [s.duration_s for n, s in poller.scans.items() if n >= scan_at_call and s.first_seen <= until]
    rnd.ack_scan_s = max(during) if during else float("nan")

    # 4: clear the fault (levels return), reset the interlock (trips return), confirm the trips
    start = len(bench.events.items)
    await plant.write_values(fault, [ua.Variant(int(SensorFault.NONE), ua.VariantType.Int32)] * len(fault))
    await bench.wait_all("the levels' returns", start, levels, "ActiveState/Id", False)
    interlocks = op.get_node(ua.NodeId(paths.plc.interlocks, idx))
    await interlocks.call_method(ua.NodeId(paths.plc.interlock_reset, idx))
    await bench.wait_all("the trips' returns", start, trips, "ActiveState/Id", False)
    rnd.return_events = len({e["NodeId"] for e in bench.since(start, cids, "ActiveState/Id", False)})
    ids = bench.latest(trips)
    start = len(bench.events.items)
    confirms = [
        ua.CallMethodRequest(ObjectId=c, MethodId=CONFIRM, InputArguments=_comment_args(ids[c], "reset"))
        for c in trips
    ]
    bad = [s for s in await _call(op, confirms) if s != "Good"]
    if bad:
        raise RuntimeError(f"Confirm answered {bad}")
    confirmed = await bench.wait_all("the confirmed events", start, trips, "ConfirmedState/Id", True)
    rnd.confirm_events = len({e["NodeId"] for e in confirmed})
    _, seen = await poller.read()
    rnd.overruns_after = seen.overruns
    rnd.wall_s = time.perf_counter() - started
    return rnd


async def run(log_dir: Path, log: Callable[[str], None], rounds: int = ROUNDS) -> AlarmsResult:
    """The benchmark (module docstring) on a fresh stack in a temporary directory; the processes'
    logs are copied to ``log_dir``."""
    res = AlarmsResult()
    res.speed_ms = speed_reference()
    log(f"  machine speed reference {res.speed_ms:.1f} ms")
    started = time.perf_counter()
    data = flood_site()
    site = SiteConfig.model_validate(data)
    assert site.plc is not None
    res.scan_period_s = site.plc.scan_period_s
    from tanklab.alarms.definitions import plc_alarms

    res.site_conditions = len(plc_alarms(site))
    tanks = site.tank_names
    log_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="tanklab-alarms-") as tmp:
        root = Path(tmp)
        logins = provision(root / "home")
        config = root / "site.yaml"
        config.write_text(yaml.safe_dump(data), encoding="utf-8")
        stack = Stack(
            config,
            free_base_port(3),
            speed=1.0,
            state_file=root / "plant-state.json",
            home=logins.home.root,
            log_dir=root,
            logins=logins,
        )
        try:
            await stack.up(("plant", "plc"))
            res.startup_s = time.perf_counter() - started
            await _rounds(stack, logins, tanks, res, rounds, log)
        except Exception as e:
            res.errors.append(f"{type(e).__name__}: {e}")
            log(f"  alarms FAILED: {type(e).__name__}: {e}")
        finally:
            await stack.down()
            res.left = tankctl_pids_on(stack.base, 2)
            for name, text in stack.logs.items():
                (log_dir / name).write_text(text, encoding="utf-8")
        plc_log = "".join(t for n, t in sorted(stack.logs.items()) if n.startswith("plc"))
        res.plc = Lateness("PLC of the flood site, speed 1", 1.0, float("nan"))
        parse_lateness(plc_log, res.plc)
    res.wall_s = time.perf_counter() - started
    return res


async def _rounds(
    stack: Stack, logins: Logins, tanks: list[str], res: AlarmsResult, rounds: int, log: Callable[[str], None]
) -> None:
    bench = Bench(stack, logins, tanks)
    plc_pid = stack.pid("plc")
    async with (
        session(stack.plc_url, logins, "engineer") as sub_client,
        session(stack.plc_url, logins, "engineer") as op,
        session(stack.plc_url, logins, "engineer") as poll_client,
        session(stack.plant_url, logins, "engineer") as plant,
    ):
        idx = await op.get_namespace_index("urn:tanklab")
        pidx = await plant.get_namespace_index("urn:tanklab")
        sub = await sub_client.create_subscription(100, bench.events)
        await sub.subscribe_events(
            ua.ObjectIds.Server, ua.ObjectIds.BaseEventType, evfilter=event_filter(FIELDS)
        )
        bias = [plant.get_node(ua.NodeId(paths.plant.lt(t).fault_value, pidx)) for t in tanks]
        await plant.write_values(bias, [ua.Variant(BIAS_M, ua.VariantType.Double)] * len(bias))
        poller = Poller(poll_client, idx, tanks)
        poller.start()
        try:
            await wait_for("the PLC's first scans", lambda: len(poller.scans) >= 2, 30.0)
            res.overruns_start = min(poller.scans.items())[1].overruns
            for i in range(rounds):
                mode = ONE_CALL if i % 2 == 0 else SEPARATE
                try:
                    rnd = await one_round(
                        bench,
                        i + 1,
                        mode,
                        plant=plant,
                        pidx=pidx,
                        op=op,
                        idx=idx,
                        poller=poller,
                        plc_pid=plc_pid,
                        period_s=res.scan_period_s,
                    )
                except Exception as e:
                    rnd = Round(i + 1, mode, error=f"{type(e).__name__}: {e}")
                    res.errors.append(f"round {i + 1}: {rnd.error}")
                    res.rounds.append(rnd)
                    log(f"  round {i + 1} FAILED: {rnd.error}")
                    break
                res.rounds.append(rnd)
                log(
                    f"  round {i + 1} ({mode}): {rnd.activation_events} active in "
                    f"{rnd.activation_times} scan(s), last after {1e3 * rnd.activation_latency_s:.0f} ms, "
                    f"scan {1e3 * rnd.activation_scan_s:.1f} ms; {rnd.ack_good} acks Good, last event after "
                    f"{1e3 * rnd.ack_latency_s:.0f} ms; overruns {rnd.overruns_after}"
                )
            _, seen = await poller.read()
            res.overruns_end = seen.overruns
        finally:
            await poller.stop()
