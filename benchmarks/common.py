"""Shared pieces of the benchmarks: summaries of samples, goals, the machine, sites, scenario.

A :class:`Summary` (:mod:`tanklab_testing.stats`, shared with the test-support package) is
what every table shows: n, median and p99 (``numpy.percentile``, linear
interpolation), plus min and max. A :class:`Goal` pairs a target from the issue with the
measured value and says met / not met.
"""

from __future__ import annotations

import math
import os
import platform
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from tanklab.config import SiteConfig, load_site
from tanklab_io.ua_client import ClientSetup
from tanklab_testing.stats import Summary  # noqa: F401  (re-exported: the benchmarks take it from here)

ROOT = Path(__file__).resolve().parents[1]
ENERGIES = ROOT / "configs" / "three_tank_energies_sim.yaml"
"""The default config (``tankctl``'s default site): the benchmark scenario runs on it."""
KORTELA = ROOT / "configs" / "three_tank_kortela.yaml"
"""The OPC UA MPC paper's plant: the MPC timing runs on it."""

SCENARIO_STEP_AT_S = 10.0
"""The benchmark scenario: LIC1's setpoint steps by ``SCENARIO_STEP_M`` at this model time [s]."""
SCENARIO_STEP_M = 0.05
SCENARIO_DURATION_S = 1000.0


@dataclass(frozen=True)
class Goal:
    """A target of the issue against its measurement."""

    name: str
    target: str
    measured: str
    met: bool | None  # None: could not be measured
    note: str = ""

    @property
    def verdict(self) -> str:
        if self.met is None:
            return "not measured"
        return "met" if self.met else "**not met**"


def fmt(value: float, digits: int = 3) -> str:
    """A number with ``digits`` significant digits, plain notation where reasonable."""
    if value is None or not math.isfinite(value):
        return "n/a"
    if value == 0:
        return "0"
    if float(value).is_integer() and abs(value) < 1e6:
        return f"{int(value):,}"
    mag = math.floor(math.log10(abs(value)))
    if mag >= 6 or mag <= -4:
        return f"{value:.{digits - 1}e}"
    decimals = max(0, digits - 1 - mag)
    return f"{value:,.{decimals}f}"


def load(path: Path) -> SiteConfig:
    """A site config, without environment overrides."""
    return load_site(path)


def with_horizon(site: SiteConfig, horizon: int) -> SiteConfig:
    """A copy of ``site`` whose supervisor MPC uses ``horizon``."""
    copy = site.model_copy(deep=True)
    if copy.supervisor is None:
        raise ValueError(f"site {site.name!r} has no supervisor section")
    copy.supervisor.mpc.horizon = horizon
    return copy


# ----------------------------------------------------------------------------------------------
# the machine
# ----------------------------------------------------------------------------------------------
PACKAGES = ("numpy", "scipy", "osqp", "asyncua", "cvxpy", "do-mpc", "casadi", "clarabel")


def cpu_model() -> str:
    """The CPU model name from /proc/cpuinfo (or the platform's processor string)."""
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return platform.processor() or "unknown"
    match = re.search(r"^model name\s*:\s*(.+)$", text, re.MULTILINE)
    return match.group(1).strip() if match else (platform.processor() or "unknown")


def versions(names: Sequence[str] = PACKAGES) -> dict[str, str]:
    """Installed versions of the named distributions ("not installed" when missing)."""
    out: dict[str, str] = {}
    for name in names:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


SPEED_REFERENCE_LOOPS = 20_000
"""Iterations of :func:`speed_reference`'s workload."""


def speed_reference(repeats: int = 7) -> float:
    """Median wall time [ms] of a fixed workload shaped like the co-simulation's scan: Python
    float arithmetic on a few values and small numpy arrays built and read back (``tolist``,
    ``np.array``), :data:`SPEED_REFERENCE_LOOPS` times.

    The machine this runs on is shared and its speed drifts (by 40 % within a day and by 2x
    between days, measured: 8.6 ms one day, 18.6 ms another): the same code's co-simulation ran
    20,080x and 12,160x real time hours apart. Measured at the start and the end of a run (and
    at the start of a section that also runs alone), this number says how fast the machine was,
    so runs of different days can be compared (lower is faster) and the goals on times are
    stated at :data:`REFERENCE_SPEED_MS` (decision 0036).
    """
    samples = []
    base = np.array([0.31, 0.27, 0.05])
    for _ in range(repeats):
        t0 = time.perf_counter()
        a = base
        for _ in range(SPEED_REFERENCE_LOOPS):
            x0, x1, x2 = a.tolist()
            h = 0.5 * (math.sqrt(x0) - math.sqrt(x1)) + 1e-4 * x2
            a = np.array([x0 - 1e-9 * h, x1 + 1e-9 * h, x2])
        samples.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(samples))


REFERENCE_SPEED_MS = 11.2
"""The machine speed reference [ms] every goal on a time is stated at (issue #22, decision 0036).

11.2 ms is the value the MPC's step-time goals were set at (decision 0027); this workload has
measured from 8.5 ms (an idle day) to 22.5 ms over full runs on this shared machine. A time
measured at speed reference ``s`` is stated as ``time x REFERENCE_SPEED_MS / s``, a rate (a
real-time factor, model seconds per wall second) as ``rate x s / REFERENCE_SPEED_MS``: see
:func:`seconds_at_reference` and :func:`rate_at_reference`."""


def speed_known(speed_ms: float) -> bool:
    """A speed reference [ms] that can scale a measurement (finite and positive)."""
    return math.isfinite(speed_ms) and speed_ms > 0


def seconds_at_reference(measured_s: float, speed_ms: float) -> float:
    """A time measured at machine speed reference ``speed_ms`` [ms], stated at
    :data:`REFERENCE_SPEED_MS`: ``measured x REFERENCE_SPEED_MS / speed_ms`` (any unit of time in,
    the same unit out). An unknown speed (NaN, <= 0) leaves the time as measured.

    Example: 6.61 s at 18.6 ms is 6.61 x 11.2 / 18.6 = 3.98 s at the reference speed.
    """
    return measured_s * REFERENCE_SPEED_MS / speed_ms if speed_known(speed_ms) else measured_s


def rate_at_reference(measured: float, speed_ms: float) -> float:
    """A rate (real-time factor, model seconds per wall second) measured at machine speed
    reference ``speed_ms`` [ms], stated at :data:`REFERENCE_SPEED_MS`: ``measured x speed_ms /
    REFERENCE_SPEED_MS``. An unknown speed (NaN, <= 0) leaves the rate as measured.

    Example: 15,867x at 18.6 ms is 15,867 x 18.6 / 11.2 = 26,351x at the reference speed.
    """
    return measured * speed_ms / REFERENCE_SPEED_MS if speed_known(speed_ms) else measured


def at_reference_text(scaled: str, measured: str, speed_ms: float) -> str:
    """A goal's measured cell for a number stated at the reference speed: ``"X at the reference
    speed (measured Y; speed reference Z ms)"``, or ``"Y (no speed reference: not scaled)"``."""
    if not speed_known(speed_ms):
        return f"{measured} (no speed reference: not scaled)"
    return f"{scaled} at the reference speed (measured {measured}; speed reference {fmt(speed_ms)} ms)"


def machine() -> dict[str, str]:
    """What the document's header states about the machine."""
    load1, load5, _ = os.getloadavg()
    info = {
        "CPU": cpu_model(),
        "cores (os.cpu_count)": str(os.cpu_count()),
        "cores usable (sched_getaffinity)": str(len(os.sched_getaffinity(0))),
        "OS": f"{platform.system()} {platform.release()} ({platform.machine()})",
        "Python": f"{platform.python_implementation()} {platform.python_version()}",
        "load average at start (1 / 5 min)": f"{load1:.2f} / {load5:.2f}",
    }
    try:
        mem = Path("/proc/meminfo").read_text(encoding="utf-8").splitlines()[0].split()[1]
        info["memory"] = f"{int(mem) / 2**20:.1f} GiB"
    except (OSError, IndexError, ValueError):
        pass
    from threadpoolctl import threadpool_info

    pools = [f"{p['internal_api']} {p.get('version') or ''}: {p['num_threads']}" for p in threadpool_info()]
    info["BLAS threads (tanklab_io.threads)"] = "; ".join(pools) or "no BLAS loaded"
    return info


_BENCH_HOME: Path | None = None


def bench_home() -> Path:
    """The benchmarks' own security home (PKI and an engineer login), made once per run in a
    temporary directory: benchmarks never touch the user's ``~/.config/tanklab``."""
    global _BENCH_HOME
    if _BENCH_HOME is None:
        import atexit
        import shutil
        import tempfile

        from tanklab_io.home import SecurityHome, provision

        root = Path(tempfile.mkdtemp(prefix="tanklab-bench-home-"))
        atexit.register(shutil.rmtree, root, True)
        provision(SecurityHome(root))
        _BENCH_HOME = root
    return _BENCH_HOME


def cli_setup() -> ClientSetup:
    """A :class:`tanklab_io.ua_client.Link` setup logging in as the bench home's engineer."""
    from tanklab_io.home import SecurityHome
    from tanklab_io.ua_security import cli_identity, client_setup

    return client_setup(cli_identity(SecurityHome(bench_home()), {}))
