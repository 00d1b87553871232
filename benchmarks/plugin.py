"""Section 16: the cost of the supervisory-controller interface (decision 0054).

The shipped MPC run directly (:meth:`supervisor.cycle.SupervisorCore.cycle`, the path before the
interface) against the same MPC through the interface (:class:`supervisor.host.ControllerHost`
around :class:`supervisor.controller.ShippedController`: the step call, the CPU-time budget
measurement, the whole-output check, the report), in one process, interleaved: the snapshots of a
closed-loop co-simulation (Energies three-tank site in MPC mode, a 0.05 m step of LIC1's setpoint
at 10 s) are replayed into two fresh cores, one direct and one through the host, cycle by cycle,
the order alternating each cycle; each call is timed with ``time.perf_counter``. Both cores see the
same snapshots, so they do the same work (their actions are compared: identical). Overhead =
median(interface) / median(direct) - 1; the median of the per-cycle paired differences is the
interface's own cost per cycle.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from benchmarks.common import ROOT, Goal, fmt, speed_reference
from benchmarks.report.base import table
from supervisor.controller import ShippedController
from supervisor.cycle import PlcSnapshot, SupervisorCore
from supervisor.host import ControllerHost
from tankctl.cosim import CoSimulation
from tanklab.config import load_site
from tanklab.enums import SupervisorMode

GOAL_PCT = 5.0
"""The interface may cost at most this much more per cycle than the direct path [%]."""


@dataclass
class PluginBench:
    cycles: int = 0
    rounds: int = 0
    direct_s: list[float] = field(default_factory=list)
    interface_s: list[float] = field(default_factory=list)
    identical: bool = True
    speed_ms: float = 0.0
    errors: list[str] = field(default_factory=list)

    @property
    def overhead_pct(self) -> float:
        return (statistics.median(self.interface_s) / statistics.median(self.direct_s) - 1.0) * 100.0

    @property
    def paired_us(self) -> float:
        return statistics.median(b - a for a, b in zip(self.direct_s, self.interface_s, strict=True)) * 1e6


def _snapshots(duration_s: float) -> list[PlcSnapshot]:
    site = load_site(ROOT / "configs" / "three_tank_energies_sim.yaml")
    for i, level in enumerate((0.4, 0.2, 0.3)):
        site.plant.tanks[i].initial_level_m = level
    sim = CoSimulation(site, supervisor_mode="MPC")
    snaps: list[PlcSnapshot] = []
    for _ in range(round(duration_s / sim.ts_s)):
        if abs(sim.t_s - 10.0) < 1e-9:
            sim.plc.set_sp("LIC1", sim.plc.loop("LIC1").sp_m + 0.05)
        sim.step()
        snap = sim.port.snapshot()
        assert snap is not None
        snaps.append(snap)
    return snaps


def run(log: Callable[[str], None], *, duration_s: float = 600.0, rounds: int = 3) -> PluginBench:
    res = PluginBench(rounds=rounds)
    res.speed_ms = speed_reference()
    site = load_site(ROOT / "configs" / "three_tank_energies_sim.yaml")
    snaps = _snapshots(duration_s)
    log(f"  {len(snaps)} snapshots recorded; {rounds} rounds of direct / interface, interleaved")
    clock = time.perf_counter
    for r in range(rounds):
        direct = SupervisorCore(site)
        direct.request_mode(SupervisorMode.MPC)
        through = SupervisorCore(site)
        through.request_mode(SupervisorMode.MPC)
        host = ControllerHost(site, ShippedController(site, core=through), through)
        for k, snap in enumerate(snaps):
            first_direct = (k + r) % 2 == 0
            for which in (0, 1) if first_direct else (1, 0):
                t0 = clock()
                if which == 0:
                    a = direct.cycle(snap)
                    res.direct_s.append(clock() - t0)
                else:
                    b = host.cycle(snap)
                    res.interface_s.append(clock() - t0)
            if (a.remote_mv, a.modes, a.gains) != (b.remote_mv, b.modes, b.gains):
                res.identical = False
        res.cycles += len(snaps)
        log(f"  round {r + 1}: overhead so far {res.overhead_pct:+.2f} %")
    res.speed_ms = (res.speed_ms + speed_reference()) / 2
    if not res.identical:
        res.errors.append("plugin: the interface's actions differ from the direct path's")
    return res


def goals(res: PluginBench) -> list[Goal]:
    """The interface costs at most 5 % more per MPC cycle than the direct path."""
    if not res.direct_s:
        return [Goal("shipped MPC through the controller interface", f"<= {GOAL_PCT:g} %", "n/a", None)]
    return [
        Goal(
            "shipped MPC through the controller interface vs direct",
            f"<= {GOAL_PCT:g} % per cycle",
            f"{res.overhead_pct:+.2f} % (medians {fmt(statistics.median(res.direct_s) * 1e3)} and "
            f"{fmt(statistics.median(res.interface_s) * 1e3)} ms)",
            res.overhead_pct <= GOAL_PCT,
            f"section 16: {res.cycles} cycles each, interleaved; paired difference {fmt(res.paired_us)} us",
        )
    ]


def markdown(res: PluginBench) -> str:
    """Section 16 of the benchmark document."""
    d, i = res.direct_s, res.interface_s
    rows = [
        [
            name,
            str(len(x)),
            fmt(statistics.median(x) * 1e3),
            fmt(statistics.quantiles(x, n=10)[0] * 1e3),
            fmt(statistics.quantiles(x, n=10)[-1] * 1e3),
            fmt(statistics.fmean(x) * 1e3),
        ]
        for name, x in (("direct: SupervisorCore.cycle", d), ("interface: ControllerHost.cycle", i))
    ]
    lines = [
        "## 16. The supervisory-controller interface: its cost per MPC cycle",
        "",
        "`benchmarks/plugin.py` (`python -m benchmarks.run --only plugin`): the shipped MPC's cycle "
        "called directly (`SupervisorCore.cycle`, the path before decision 0054) against the same "
        "cycle through the interface (`ControllerHost.cycle` around `ShippedController`: the step "
        "call, the CPU-budget gate, the whole-output check), in one process. The snapshots of a "
        "closed-loop co-simulation (Energies three-tank site in MPC mode, a 0.05 m step of LIC1's "
        "setpoint at 10 s) are replayed into two fresh cores, one direct and one through the host, "
        "cycle by cycle, the order alternating each cycle; each call timed with `time.perf_counter`. "
        "Both see the same snapshots, so they do the same work (their actions are compared). "
        "Overhead = median(interface) / median(direct) - 1. "
        f"{res.rounds} rounds of {res.cycles // max(res.rounds, 1)} cycles. Machine speed reference "
        f"{fmt(res.speed_ms)} ms.",
        "",
        *table(["path", "cycles", "median [ms]", "p10 [ms]", "p90 [ms]", "mean [ms]"], rows, "lrrrrr"),
        "",
        f"Overhead of the interface: **{res.overhead_pct:+.2f} %** of the median cycle "
        f"(goal <= {GOAL_PCT:g} %); "
        f"median paired difference {fmt(res.paired_us)} us per cycle. Actions of the two paths "
        + ("identical at every cycle." if res.identical else "**differ** (see the errors)."),
        "",
    ]
    return "\n".join(lines)
