"""What the controllers can reject: which injected inflows the plant passes without spilling,
in the worst state the PLC allows (:class:`InflowAuthority`), and how far a level rises in one
scan (:func:`scan_rise_m`). Steady-state bounds of the site, used by the random scenarios
(:mod:`tankctl.randomized`) to draw passable inflows and to explain a spill."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import root

from plant_sim.linearize import level_rhs
from plant_sim.models import FloatArray, PlantInputs, TankNetwork, default_inputs
from tanklab.config import SiteConfig


class InflowAuthority:
    """Which injected inflows the plant passes without spilling, in the worst state the PLC allows.

    The PLC's only means against a rising level is to stop pumps, so an injected inflow d >= 0
    (n_tanks,) [m^3/s] can spill whatever the controllers do. The worst state for draining it:
    every pump-fed tank held at the highest level its loop and interlock allow,
    H_j = min(HH_j, sp_max_j, Hmax_j) (a fuller neighbour takes less through the orifice between
    them), leaks closed, no outflow disturbance. Tanks without a pump settle where dh/dt = 0
    with the held levels fixed; a held tank that would need a negative pump flow (it receives
    more than it drains) is released with its pump stopped and settles too. ``d`` passes when
    every settled tank is at or below its Hmax. A steady-state bound, on the configured valve
    openings: it says which inflows no control can pass, not how a transient runs.

    Example, the Energies site (T1 -> T3 -> T2 -> drain, Hmax 0.62 m, HH 0.58 m): an inflow
    into T3 leaves only through V32 into T2, which LIC2 may hold at 0.58 m, so about
    mu Ap sqrt(2 g) sqrt(0.62 - 0.58) = 2.2e-5 m^3/s passes, a fifth of the 1.2e-4 m^3/s the
    Disturbance nodes accept (:meth:`capacities`).

    Raises
    ------
    ValueError
        The site has no PLC program.
    """

    def __init__(self, site: SiteConfig) -> None:
        if site.plc is None:
            raise ValueError(f"site {site.name!r} has no plc section")
        self.site = site
        self.net = TankNetwork.from_config(site.plant)
        n = self.net.n_tanks
        base = default_inputs(self.net, site.plant)
        self._u = replace(base, leak_openings=np.zeros(n), disturbances_m3_s=np.zeros(n))
        hold = self.net.hmax_m.copy()
        for il in site.plc.interlocks:
            k = site.tank_names.index(il.tank)
            hold[k] = min(hold[k], il.high_high_m)
        for lp in site.plc.loops:
            k = site.tank_names.index("T" + lp.pv[2:])
            hold[k] = min(hold[k], lp.sp_max_m)
        self.hold_m = hold
        """(n_tanks,) level each pump-fed tank is held at in the worst case [m]."""
        self._fed = {int(k) for k in self.net.pump_tank}
        self.limit_m3_s = site.plant.disturbance_limit_m3_s

    def passes(self, inflows_m3_s: ArrayLike) -> bool:
        """Whether the inflows (n_tanks,) [m^3/s] settle with no tank above its Hmax.

        Negative entries (outflows) count as 0: one may end at any time.

        Raises
        ------
        ValueError
            The steady-state solve fails.
        """
        net = self.net
        n = net.n_tanks
        d = np.maximum(np.asarray(inflows_m3_s, dtype=float), 0.0)
        if d.shape != (n,):
            raise ValueError(f"need {n} inflows, got shape {d.shape}")
        u = replace(self._u, disturbances_m3_s=d)
        free = set(range(n)) - self._fed
        while True:
            h = self._settle(u, sorted(free))
            dh = level_rhs(net, h, np.zeros(net.n_pumps), u)
            gaining = {k for k in range(n) if k not in free and dh[k] > 0.0}
            if not gaining:
                return bool(np.all(h <= net.hmax_m))
            free |= gaining

    def headroom(self, inflows_m3_s: ArrayLike, tank: int, *, rtol: float = 1e-6) -> float:
        """Largest inflow into ``tank`` (others as given) that passes, in [0, limit] [m^3/s].

        Bisection (levels rise with every inflow) to ``rtol`` of the disturbance limit; the
        value returned passes.
        """
        d = np.maximum(np.asarray(inflows_m3_s, dtype=float), 0.0)

        def ok(x: float) -> bool:
            d[tank] = x
            return self.passes(d)

        if ok(self.limit_m3_s):
            return self.limit_m3_s
        lo, hi = 0.0, self.limit_m3_s
        if not ok(lo):
            return 0.0
        while hi - lo > rtol * self.limit_m3_s:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ok(mid) else (lo, mid)
        return lo

    def capacities(self) -> dict[str, float]:
        """Largest inflow into each tank alone that passes [m^3/s], by tank name."""
        zero = np.zeros(self.net.n_tanks)
        return {name: self.headroom(zero, i) for i, name in enumerate(self.site.tank_names)}

    def _settle(self, u: PlantInputs, free: list[int]) -> FloatArray:
        """Levels with the free tanks where dh/dt = 0 (pumps into them stopped), the rest held."""
        net = self.net
        hold = self.hold_m

        def levels(z: FloatArray) -> FloatArray:
            h = hold.copy()
            h[free] = z
            return h

        def residual(z: FloatArray) -> FloatArray:
            # In m^3/s per largest pump flow, so the unknowns and the residual are O(1).
            q = level_rhs(net, levels(z), np.zeros(net.n_pumps), u) * net.area_m2
            return np.asarray(q[free] / net.pump_max_flow_m3_s.max(), dtype=float)

        if not free:
            return hold.copy()
        sol = root(residual, net.hmax_m[free], method="hybr", options={"xtol": 1e-14})
        if np.max(np.abs(residual(sol.x))) > 1e-10:
            raise ValueError(f"no steady state of tanks {free}: {sol.message}")
        return levels(np.asarray(sol.x, dtype=float))


def inflow_capacity_m3_s(site: SiteConfig) -> dict[str, float]:
    """Largest constant inflow into each tank alone that the plant passes in the worst state
    the PLC allows [m^3/s], by tank name (:class:`InflowAuthority`)."""
    return InflowAuthority(site).capacities()


def scan_rise_m(site: SiteConfig) -> dict[str, float]:
    """Largest level rise of each tank over one scan from its pumps alone [m], by tank name.

    sum_j Q_max,j Ts / A_i over the pumps feeding tank i (0 for a tank without a pump): what
    the level may gain between the scan that last read it below HH and the next one. A tank
    whose Hmax - HH is smaller can spill before its interlock sees HH.

    Raises
    ------
    ValueError
        The site has no PLC program.
    """
    if site.plc is None:
        raise ValueError(f"site {site.name!r} has no plc section")
    ts = site.plc.scan_period_s
    return {
        t.name: sum(p.max_flow_m3_s for p in site.plant.pumps if p.feeds == t.name) * ts / t.area_m2
        for t in site.plant.tanks
    }
