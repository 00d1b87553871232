"""The HMI's latency and CPU (issue 17): an OPC UA value change to the DOM update that shows it,
measured in a real headless Chromium, and the CPU of the browser and of the HMI server.

**The stack.** Plant, PLC, supervisor and historian of the Energies site as real processes
(:class:`tanklab_testing.stack.Stack`, the benchmark's own provisioned security home), at speed 1:
the PLC scans every 1 s of wall time (``scan_period_s: 1.0``), the plant publishes its values as
its model steps. ``tankctl hmi`` runs against them on a free loopback port at its default poll
(:data:`hmi.hub.POLL_S`, 0.1 s: one Read of the live set per tier and logged-in user).

**The browser.** Debian's ``/usr/bin/chromium`` headless, driven by ``/usr/bin/chromedriver``
through Selenium (nothing downloaded), logs in through the login form as the home's engineer.
The page itself measures: for every value of every ``values`` message after the first (which
carries old values too), once the store's listeners have redrawn the DOM synchronously, it
records ::

    latency = (performance.timeOrigin + performance.now()) / 1000 - t_source   [s]

where ``t_source`` is the value's OPC UA SourceTimestamp as the server sent it (``t`` in the
message, epoch s): one clock, this machine's, for the tiers, the HMI and the browser
(``window.tanklabHmi.parts.latency``, the latest 5000 per browser window: about the last minute
at the Energies site's 80 changed values a second). The samples of a window are cleared at
its start and read at its end; p50 and p99 are nearest-rank percentiles (:func:`percentile`).

**The windows.** 1 client: one browser window for :data:`WINDOW_S`. 20 clients: 19 more windows
of the same Chromium (one profile, so one login: the 20 WebSockets share one user's hub and its
one poll, as 20 operator screens of one user would), all of them sampled. 20 separate Chromium
instances would be 20 browsers' start-up and memory on a 2-core machine; 20 windows of one
browser are 20 renderer processes, the realistic cost of 20 screens.

**CPU** from ``/proc/<pid>/stat`` (utime + stime, in clock ticks) over the window ::

    cpu% = 100 * sum_p (ticks_p(end) - ticks_p(start)) / CLK_TCK / wall_s   [% of one core]

for the HMI server (its one process) and for the browser (every descendant of chromedriver:
Chromium's browser, GPU, utility and renderer processes; a process born in the window counts
from 0, one that died in it is lost). Selenium's own calls are outside the windows.
"""

from __future__ import annotations

import asyncio
import math
import os
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmarks.common import ENERGIES, Goal, fmt, speed_reference
from tanklab_testing.browser import CHROMEDRIVER, CHROMIUM, chrome_options
from tanklab_testing.logins import provision
from tanklab_testing.procs import TankctlProcess, descendants, free_base_port, free_port, tankctl_pids_on
from tanklab_testing.stack import Stack

WINDOW_S = 60.0
"""Wall time of one measurement window [s]."""
QUICK_WINDOW_S = 20.0
CLIENTS = (1, 20)
"""Browser windows of the two measurements."""
GOAL_P99_S = 0.25
"""Issue 17: p99 of value change to DOM update <= 250 ms at a 1 s scan."""
POLL_S = 0.1
"""The HMI's poll (its default, hmi.hub.POLL_S) [s]."""
TIERS = ("plant", "plc", "supervisor", "historian")
CLK_TCK = os.sysconf("SC_CLK_TCK")


# ---- the pure parts ----------------------------------------------------------------------------


def percentile(samples: Sequence[float], q: float) -> float:
    """The nearest-rank ``q``-th percentile (0 < q <= 100) of ``samples``: the smallest sample
    with at least q % of the samples at or below it; nan for no samples."""
    if not 0 < q <= 100:
        raise ValueError(f"q must be in (0, 100], got {q}")
    if not samples:
        return float("nan")
    ordered = sorted(samples)
    rank = math.ceil(q * len(ordered) / 100.0)
    return ordered[max(rank, 1) - 1]


def stat_ticks(text: str) -> int:
    """utime + stime [clock ticks] of one ``/proc/<pid>/stat`` line (the command name, in
    parentheses, may hold spaces and parentheses: the fields are counted after the last ``)``)."""
    fields = text.rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])


def cpu_percent(before: Mapping[int, int], after: Mapping[int, int], wall_s: float, clk_tck: int) -> float:
    """% of one core the processes of ``after`` used since ``before`` (ticks by pid; a pid not
    in ``before`` was born meanwhile and counts from 0) over ``wall_s`` seconds."""
    if not wall_s > 0:
        return float("nan")
    ticks = sum(t - before.get(pid, 0) for pid, t in after.items())
    return 100.0 * ticks / clk_tck / wall_s


@dataclass
class Window:
    """One measurement: ``clients`` browser windows for ``wall_s`` seconds."""

    clients: int
    wall_s: float = float("nan")
    samples: list[float] = field(default_factory=list)
    """Every value's source-to-DOM latency of every window [s]."""
    browser_cpu_pct: float = float("nan")
    server_cpu_pct: float = float("nan")
    browser_processes: int = 0

    @property
    def p50_s(self) -> float:
        return percentile(self.samples, 50)

    @property
    def p99_s(self) -> float:
        return percentile(self.samples, 99)

    @property
    def max_s(self) -> float:
        return max(self.samples) if self.samples else float("nan")


@dataclass
class HmiResult:
    """Both windows and how they were made."""

    window_s: float
    poll_s: float = POLL_S
    windows: list[Window] = field(default_factory=list)
    speed_reference_ms: float = float("nan")
    load_average: tuple[float, float, float] = (float("nan"),) * 3
    errors: list[str] = field(default_factory=list)
    left: list[int] = field(default_factory=list)
    """tankctl processes left on the stack's ports after the stop."""


def goals(res: HmiResult) -> list[Goal]:
    """Issue 17's latency goal at 1 client (and, as stated, at 20)."""
    out = []
    for w in res.windows:
        name = f"HMI value change to DOM update p99 at a 1 s scan, {w.clients} client(s)"
        if not w.samples:
            out.append(Goal(name, f"<= {1e3 * GOAL_P99_S:.0f} ms", "n/a", None))
            continue
        measured = f"{fmt(1e3 * w.p99_s)} ms (p50 {fmt(1e3 * w.p50_s)} ms, {len(w.samples):,} values)"
        out.append(
            Goal(
                name,
                f"<= {1e3 * GOAL_P99_S:.0f} ms",
                measured,
                w.p99_s <= GOAL_P99_S,
                f"section 15, poll {res.poll_s:g} s",
            )
        )
    return out


def markdown(res: HmiResult) -> str:
    """Section 15 of the benchmark document."""
    load = ", ".join(f"{x:.1f}" for x in res.load_average)
    lines = [
        "## 15. HMI: value change to DOM update, browser and server CPU (1 s scan, speed 1)",
        "",
        "`benchmarks/hmi.py` (`python -m benchmarks.run --only hmi`): plant, PLC, supervisor and "
        "historian of the Energies site as real processes at speed 1 (the PLC scans every 1 s), "
        f"`tankctl hmi` against them at its {res.poll_s:g} s poll, and Debian's headless Chromium "
        "(Selenium) logged in through the form as the engineer. The page records, for every value "
        "of every `values` message after the first, the time the DOM update that shows it ends "
        "(`performance.timeOrigin + performance.now()`) minus the value's OPC UA SourceTimestamp "
        "sent in the message (one clock: this machine's); each window keeps its latest 5,000 "
        "samples (the page's buffer: at about 80 changed values a second, the last minute). "
        "20 clients are 20 windows of one "
        "Chromium (one login, 20 WebSockets on one user's poll; 20 browser instances are not "
        "realistic on 2 cores), all sampled. CPU: utime + stime from `/proc/<pid>/stat` over the "
        "window, in % of one core: the HMI server's process, and the browser's (every process "
        f"under chromedriver). Windows of {res.window_s:g} s; machine speed reference "
        f"{fmt(res.speed_reference_ms)} ms, load average at the start {load}.",
        "",
        "| clients | window [s] | values | p50 [ms] | p99 [ms] | max [ms] | browser CPU [% core] "
        "| browser processes | HMI server CPU [% core] |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for w in res.windows:
        lines.append(
            f"| {w.clients} | {fmt(w.wall_s)} | {len(w.samples):,} | {fmt(1e3 * w.p50_s)} | "
            f"{fmt(1e3 * w.p99_s)} | {fmt(1e3 * w.max_s)} | {fmt(w.browser_cpu_pct)} | "
            f"{w.browser_processes} | {fmt(w.server_cpu_pct)} |"
        )
    lines += [
        "",
        f"Goal (issue 17): p99 <= {1e3 * GOAL_P99_S:.0f} ms at a 1 s scan. tankctl processes left on "
        f"the stack's ports after the stop: {len(res.left)}.",
    ]
    if res.errors:
        lines += ["", *[f"- error: {e}" for e in res.errors]]
    return "\n".join(lines) + "\n"


# ---- the measurement ---------------------------------------------------------------------------


def _ticks(pids: Iterable[int]) -> dict[int, int]:
    out = {}
    for pid in pids:
        try:
            out[pid] = stat_ticks(Path(f"/proc/{pid}/stat").read_text())
        except (OSError, IndexError, ValueError):
            continue
    return out


class _Chromium:
    """One headless Chromium (Selenium, the system's chromium and chromedriver)."""

    def __init__(self) -> None:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service

        if not (CHROMIUM.exists() and CHROMEDRIVER.exists()):
            raise RuntimeError(f"{CHROMIUM} and {CHROMEDRIVER} are needed (`make tools`)")
        opts = chrome_options(1400, 1000)
        self.driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=opts)
        self.driver.set_script_timeout(30)

    @property
    def pids(self) -> list[int]:
        """Chromium's processes (everything under chromedriver)."""
        driver_pid = self.driver.service.process.pid
        return descendants(driver_pid)

    def wait(self, script: str, timeout_s: float, what: str) -> None:
        from selenium.webdriver.support.ui import WebDriverWait

        WebDriverWait(self.driver, timeout_s, poll_frequency=0.2).until(
            lambda d: d.execute_script(script), f"waited {timeout_s} s for {what}"
        )

    def ready(self) -> None:
        self.wait(
            "return document.body.dataset.state === 'ready' && !!window.tanklabHmi"
            " && window.tanklabHmi.parts.seenValues",
            60,
            "the screen with its first values",
        )

    def login(self, url: str, user: str, password: str) -> None:
        from selenium.webdriver.common.by import By

        self.driver.get(url)
        self.wait("return document.body.dataset.state === 'login'", 30, "the login form")
        self.driver.find_element(By.CSS_SELECTOR, "#login-user").send_keys(user)
        self.driver.find_element(By.CSS_SELECTOR, "#login-password").send_keys(password)
        self.driver.find_element(By.CSS_SELECTOR, "#login-submit").click()
        self.ready()

    def open_window(self, url: str) -> None:
        """One more window of the same profile (the session's cookie: already logged in)."""
        self.driver.switch_to.new_window("window")
        self.driver.get(url)
        self.ready()

    def each_window(self, script: str) -> list[Any]:
        out = []
        for handle in self.driver.window_handles:
            self.driver.switch_to.window(handle)
            out.append(self.driver.execute_script(script))
        return out

    def quit(self) -> None:
        import contextlib

        with contextlib.suppress(Exception):
            self.driver.quit()


async def _window(
    chromium: _Chromium, hmi: TankctlProcess, clients: int, window_s: float, log: Callable[[str], None]
) -> Window:
    w = Window(clients)
    await asyncio.to_thread(chromium.each_window, "window.tanklabHmi.parts.latency.length = 0")
    browser_pids = chromium.pids
    server_pid = hmi.main_pid
    assert server_pid is not None
    b0, s0, t0 = _ticks(browser_pids), _ticks([server_pid]), time.monotonic()
    await asyncio.sleep(window_s)
    b1 = _ticks(set(browser_pids) | set(chromium.pids))
    s1, t1 = _ticks([server_pid]), time.monotonic()
    w.wall_s = t1 - t0
    w.browser_cpu_pct = cpu_percent(b0, b1, w.wall_s, CLK_TCK)
    w.server_cpu_pct = cpu_percent(s0, s1, w.wall_s, CLK_TCK)
    w.browser_processes = len(b1)
    lists = await asyncio.to_thread(chromium.each_window, "return window.tanklabHmi.parts.latency.slice()")
    w.samples = [float(x) for samples in lists for x in samples]
    log(
        f"  {clients} client(s): {len(w.samples)} values, p50 {fmt(1e3 * w.p50_s)} ms, "
        f"p99 {fmt(1e3 * w.p99_s)} ms; browser {fmt(w.browser_cpu_pct)} %, server {fmt(w.server_cpu_pct)} %"
    )
    return w


async def run(
    log_dir: Path, log: Callable[[str], None], window_s: float = WINDOW_S, clients: Sequence[int] = CLIENTS
) -> HmiResult:
    """Both windows against a fresh stack and HMI; every process stopped on every path."""
    res = HmiResult(window_s)
    res.speed_reference_ms = speed_reference()
    res.load_average = os.getloadavg()
    log_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="tanklab-hmi-bench-") as tmp:
        root = Path(tmp)
        logins = provision(root / "home")
        user, creds = next(iter(logins.credentials.items()))
        stack = Stack(
            ENERGIES,
            free_base_port(4),
            speed=1.0,
            state_file=root / "plant-state.json",
            home=logins.home.root,
            log_dir=root,
            logins=logins,
            tier_args={"historian": ("--store", str(root / "history.db"))},
        )
        port = free_port()
        hmi = TankctlProcess(
            *("hmi", "--config", str(ENERGIES), "--base-port", str(stack.base), "--port", str(port)),
            *("--home", str(logins.home.root), "--poll-interval", f"{POLL_S:g}"),
            name="hmi",
            log=root / "hmi.log",
            ports=[port],
        )
        chromium: _Chromium | None = None
        try:
            await stack.up(TIERS)
            await hmi.start()
            url = f"http://127.0.0.1:{port}"
            chromium = await asyncio.to_thread(_Chromium)
            await asyncio.to_thread(chromium.login, url, user, creds.password)
            opened = 1
            for n in clients:
                while opened < n:
                    await asyncio.to_thread(chromium.open_window, url)
                    opened += 1
                res.windows.append(await _window(chromium, hmi, n, window_s, log))
        except Exception as e:
            res.errors.append(f"{type(e).__name__}: {e}")
            log(f"  hmi FAILED: {type(e).__name__}: {e}")
        finally:
            if chromium is not None:
                await asyncio.to_thread(chromium.quit)
            await hmi.stop()
            await stack.down()
            res.left = tankctl_pids_on(stack.base, 4)
            for name, text in stack.logs.items():
                (log_dir / name).write_text(text, encoding="utf-8")
            if (root / "hmi.log").exists():
                (log_dir / "hmi.log").write_text((root / "hmi.log").read_text(errors="replace"))
    return res
