"""Operator commands of ``tankctl`` against a real stack (plant, PLC, supervisor at speed 20).

The stack is started once for the module, on three consecutive free loopback ports (so the
commands can find it with ``--base-port``). Commands run through typer's CliRunner and as
``python -m tankctl`` subprocesses; values are checked with an independent asyncua client.
Waits go through ``wait_until`` (bounded); assertions are on values and model time.

Until ``tankctl.cli`` mounts the commands (``tankctl.ops.register``), the same commands run on
an app built by ``register`` (in-process and with ``python -c``); once mounted, the real
``tankctl`` app and ``python -m tankctl`` are used.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import typer
from typer.testing import CliRunner

from helpers import ROOT, TEST_PASSWORDS, free_base_port, free_port, secure, wait_until
from tankctl.ops import (
    TIERS,
    SiteMismatchError,
    UsageError,
    level_bar,
    register,
    resolve_endpoints,
    sparkline,
)
from tankctl.ops import Stack as OpsStack
from tankctl.ops.stack import ENDPOINT_TIERS
from tanklab.config import load_site
from tanklab.enums import LoopMode, SupervisorMode
from tanklab.identity import SiteIdentity, canonical_json
from tanklab.tags import Tier
from tanklab_io.ua_client import resolve
from tanklab_testing.stack import Stack

CONFIG = str(ROOT / "configs/three_tank_energies_sim.yaml")
TWO_TANK = "configs/two_tank_interacting.yaml"
ENERGIES = SiteIdentity.of(load_site(CONFIG))
"""What the module's stack publishes in ``<Tier>.Identity``."""
SPEED = "20"
pytestmark = pytest.mark.process

P1_MAX = 1.2e-4
"""command_max of P1 in the Energies config: the ManualMV EURange is 0 .. P1_MAX [m^3/s]."""


# --------------------------------------------------------------------------------------------
# The stack
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Stack]:
    """The test-support :class:`Stack`, all three tiers, serving for the module's synchronous
    tests from an event loop of its own thread (stopped on every path)."""
    state = tmp_path_factory.mktemp("plant") / "plant.json"
    s = Stack(Path(CONFIG), free_base_port(), speed=float(SPEED), state_file=state)
    with s.serving():
        yield s


# --------------------------------------------------------------------------------------------
# Running commands and reading values
# --------------------------------------------------------------------------------------------

_RUNNER = (
    "import typer; from tankctl.ops import register; "
    "app = typer.Typer(pretty_exceptions_enable=False, add_completion=False); "
    "register(app); app(prog_name='tankctl')"
)


def _mounted() -> bool:
    """Whether the lead has mounted the operator commands on ``tankctl.cli.app``."""
    from tankctl import cli

    # Mounted eagerly (registered on the app) or lazily (decision 0039: the group knows the name).
    group: Any = typer.main.get_command(cli.app)
    return "setpoint" in {c.name for c in cli.app.registered_commands} or "setpoint" in group.commands


def _app() -> typer.Typer:
    if _mounted():
        from tankctl import cli

        return cli.app
    app = typer.Typer(pretty_exceptions_enable=False, add_completion=False)
    register(app)
    return app


@dataclass
class Ran:
    code: int
    stdout: str
    stderr: str


def cli(*args: str, env: dict[str, str] | None = None) -> Ran:
    """Run a command in-process through typer's CliRunner."""
    result = CliRunner().invoke(_app(), list(args), env=env)
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    ran = Ran(result.exit_code, result.stdout, result.stderr)
    assert "Traceback" not in ran.stdout + ran.stderr
    return ran


def proc(*args: str, env: dict[str, str] | None = None, timeout_s: float = 60.0) -> Ran:
    """Run a command as ``python -m tankctl ...`` (or the equivalent runner before mounting)."""
    entry = ["-m", "tankctl"] if _mounted() else ["-c", _RUNNER]
    done = subprocess.run(
        [sys.executable, *entry, *args],
        capture_output=True,
        check=False,
        text=True,
        cwd=ROOT,
        env=dict(os.environ, **(env or {})),
        timeout=timeout_s,
    )
    ran = Ran(done.returncode, done.stdout, done.stderr)
    assert "Traceback" not in ran.stdout + ran.stderr
    return ran


def base(stack: Stack) -> list[str]:
    return ["--config", CONFIG, "--base-port", str(stack.base)]


def read(url: str, *paths: str) -> list[Any]:
    """Values read by an independent client."""

    async def main() -> list[Any]:
        async with await secure(url) as client:
            nodes = await resolve(client, list(paths))
            return [await nodes[p].read_value() for p in paths]

    return asyncio.run(main())


def wait_for(url: str, path: str, ok: Callable[[Any], bool], what: str, deadline_s: float = 30.0) -> None:
    """Bounded wait until ``ok(value of path)``."""

    async def main() -> None:
        async with await secure(url) as client:
            node = (await resolve(client, [path]))[path]

            async def cond() -> bool:
                return ok(await node.read_value())

            await wait_until(cond, deadline_s, what=what)

    asyncio.run(main())


def expect(url: str, path: str, value: Any, deadline_s: float = 10.0) -> None:
    """Bounded wait until the node reads ``value`` (a scan publishing values it computed
    before the write may show the old value for one publication)."""
    wait_for(url, path, lambda v: v == value, f"{path} == {value}", deadline_s)


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


# --------------------------------------------------------------------------------------------
# Pure parts
# --------------------------------------------------------------------------------------------


def test_endpoint_precedence_flags_env_base_port_site() -> None:
    site = load_site(CONFIG)
    default = resolve_endpoints(site, urls={}, env={})
    assert default == {t: f"opc.tcp://127.0.0.1:{4840 + k}/tanklab/{t}" for k, t in enumerate(ENDPOINT_TIERS)}
    by_base = resolve_endpoints(site, urls={}, env={}, base_port=5000, host="10.0.0.7")
    assert by_base["supervisor"] == "opc.tcp://10.0.0.7:5002/tanklab/supervisor"
    env = {"TANKLAB_BASE_PORT": "6000", "TANKLAB_PLC_URL": "opc.tcp://plc.example:7000/tanklab/plc"}
    mixed = resolve_endpoints(site, urls={"plant": "opc.tcp://p:1/x"}, env=env)
    assert mixed == {
        "plant": "opc.tcp://p:1/x",  # flag
        "plc": "opc.tcp://plc.example:7000/tanklab/plc",  # environment
        "supervisor": "opc.tcp://127.0.0.1:6002/tanklab/supervisor",  # TANKLAB_BASE_PORT
        "historian": "opc.tcp://127.0.0.1:6003/tanklab/historian",
    }
    env = {"TANKLAB_HISTORIAN_ENDPOINT": "opc.tcp://h:9/tanklab/historian", "TANKLAB_HISTORIAN_URL": "x.db"}
    assert resolve_endpoints(site, urls={}, env=env)["historian"] == "opc.tcp://h:9/tanklab/historian"
    with pytest.raises(UsageError, match=re.escape("--historian-url: not an opc.tcp")):
        resolve_endpoints(site, urls={"historian": "postgresql://x"}, env={})
    assert resolve_endpoints(site, urls={}, env={}, host="h")["plc"] == "opc.tcp://h:4841/tanklab/plc"
    with pytest.raises(UsageError, match=re.escape("--plc-url: not an opc.tcp")):
        resolve_endpoints(site, urls={"plc": "http://x"}, env={})
    with pytest.raises(UsageError, match="TANKLAB_BASE_PORT must be a port number"):
        resolve_endpoints(site, urls={}, env={"TANKLAB_BASE_PORT": "abc"})
    with pytest.raises(UsageError, match=re.escape("--base-port must be 1..65532 (four consecutive ports)")):
        resolve_endpoints(site, urls={}, env={}, base_port=65533)


def test_endpoints_without_a_site_are_the_default_ones() -> None:
    default = resolve_endpoints(None, urls={}, env={})
    assert default == {t: f"opc.tcp://127.0.0.1:{4840 + k}/tanklab/{t}" for k, t in enumerate(ENDPOINT_TIERS)}


def _identity(site_config: str) -> dict[str, str]:
    site = load_site(ROOT / site_config)
    ident = SiteIdentity.of(site)
    return {"SiteName": ident.name, "ConfigDigest": ident.digest, "Config": canonical_json(site)}


def test_a_stack_checks_what_each_tier_says_it_runs() -> None:
    urls: dict[Tier, str] = dict.fromkeys(TIERS, "U")
    given = OpsStack(load_site(CONFIG), urls, source=f"--config {CONFIG}")
    given.accept("plc", "U", _identity(CONFIG))  # the same site and config: accepted
    two = SiteIdentity.of(load_site(ROOT / TWO_TANK))
    with pytest.raises(SiteMismatchError) as e:
        given.accept("plc", "U", _identity(TWO_TANK))
    assert str(e.value) == (
        f"site mismatch: plc at U runs two_tank_interacting (config {two.short}); --config {CONFIG} is "
        f"three_tank_energies_sim (config {ENERGIES.short}); give the stack's config, or no --config "
        "to take the site from the stack"
    )
    with pytest.raises(SiteMismatchError, match=r"^plant at U publishes no site identity \(Plant.Identity\)"):
        given.accept("plant", "U", {"SiteName": None, "ConfigDigest": None})
    # No site given: the first tier's published config is the site, the others must agree.
    taken = OpsStack(None, urls)
    assert not taken.resolved
    taken.accept("plc", "U", _identity(CONFIG))
    assert (taken.site.name, taken.site_identity, taken.origin) == (ENERGIES.name, ENERGIES, "plc at U")
    with pytest.raises(
        SiteMismatchError, match=r"but plc at U runs three_tank_energies_sim .* different sites"
    ):
        taken.accept("supervisor", "V", _identity(TWO_TANK))
    forged = {**_identity(CONFIG), "Config": _identity(TWO_TANK)["Config"]}
    with pytest.raises(
        SiteMismatchError, match=r"its Identity\.Config is not the config of its ConfigDigest"
    ):
        OpsStack(None, urls).accept("plc", "U", forged)


def test_sparkline_and_bar_scale_their_inputs() -> None:
    assert sparkline([0.0, 0.5, 1.0], 0.0, 1.0) == "▁▅█"
    assert sparkline([2.0, -1.0], 0.0, 1.0) == "█▁"  # clipped to the scale
    bar = level_bar(0.31, 0.465, 0.62, width=8).plain
    assert bar == "████··|·"  # half full, setpoint at 3/4


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["setpoint", "LIC9", "0.4"],
            "unknown loop 'LIC9' (the site three_tank_energies_sim has LIC1, LIC2)",
        ),
        (["leak", "T9", "0.3"], "unknown tank 'T9'"),
        (["leak", "T1", "half"], "the leak opening must be a number 0..1 or 'off'"),
        (["valve", "V99", "0.5"], "unknown valve 'V99'"),
        (["loop", "LIC1", "manual", "140"], "the manual output must be 0..100 % of the MV range, got 140"),
        (["loop", "LIC1", "auto", "40"], "an output percentage goes with manual only"),
        (["loop", "LIC1", "cascade"], "loop mode must be manual, auto or remote"),
        (["mode", "turbo"], "mode must be adaptive-pid, mpc, advisory or off"),
        (["browse", "historian"], "tier must be plant, plc or supervisor"),
        (["watch", "--interval", "0"], "--interval must be a positive number"),
        (["setpoint", "LIC1"], "Missing argument"),
    ],
)
def test_bad_arguments_exit_2_with_one_line_before_connecting(args: list[str], message: str) -> None:
    # Port 1 refuses: a message about reaching a tier would mean the check came too late.
    ran = cli(*args, "--config", CONFIG, "--base-port", "1")
    assert ran.code == 2
    assert message in one_line(ran.stderr)
    assert ran.stdout == ""


# --------------------------------------------------------------------------------------------
# Against the running stack
# --------------------------------------------------------------------------------------------


def test_setpoint_is_written_to_the_plc(stack: Stack) -> None:
    (before,) = read(stack.url("plc"), "PLC.LIC1.SP")
    ran = cli("setpoint", "LIC1", "0.45", *base(stack))
    assert ran.code == 0, ran.stderr
    assert one_line(ran.stdout) == f"PLC.LIC1.SP = 0.45 m (was {before:g} m)"
    expect(stack.url("plc"), "PLC.LIC1.SP", 0.45)
    assert cli("setpoint", "LIC1", "0.4", *base(stack)).code == 0
    expect(stack.url("plc"), "PLC.LIC1.SP", 0.4)


def test_setpoint_out_of_range_is_refused_and_the_value_stays(stack: Stack) -> None:
    (before,) = read(stack.url("plc"), "PLC.LIC1.SP")
    ran = proc("setpoint", "LIC1", "0.7", *base(stack))
    assert ran.code == 1
    assert one_line(ran.stderr) == "tankctl: PLC.LIC1.SP = 0.7 refused: BadOutOfRange"
    assert ran.stdout == ""
    assert read(stack.url("plc"), "PLC.LIC1.SP") == [before]


def test_a_role_without_the_right_is_refused_and_the_value_stays(stack: Stack) -> None:
    (before,) = read(stack.url("plc"), "PLC.LIC1.SP")
    env = {"TANKLAB_USER": "observer", "TANKLAB_PASSWORD": TEST_PASSWORDS["observer"]}
    ran = proc("setpoint", "LIC1", "0.42", *base(stack), env=env)
    assert ran.code == 1
    assert one_line(ran.stderr) == "tankctl: PLC.LIC1.SP = 0.42 refused: BadUserAccessDenied"
    assert read(stack.url("plc"), "PLC.LIC1.SP") == [before]


def test_a_refused_login_is_one_line_and_exit_2(stack: Stack) -> None:
    env = {"TANKLAB_USER": "nobody", "TANKLAB_PASSWORD": "not-a-password-at-all"}
    ran = proc("setpoint", "LIC1", "0.42", *base(stack), env=env)
    assert ran.code == 2
    assert one_line(ran.stderr) == (
        "tankctl: login as 'nobody' refused: wrong user name or password, or the account is locked "
        f"(plc at {stack.url('plc')})"
    )


def test_leak_opens_and_off_closes_through_the_environment_url(stack: Stack) -> None:
    env = {"TANKLAB_PLANT_URL": stack.url("plant")}
    ran = cli("leak", "T1", "0.3", "--config", CONFIG, env=env)
    assert ran.code == 0, ran.stderr
    assert one_line(ran.stdout).startswith("Plant.T1.Leak = 0.3 (was ")
    expect(stack.url("plant"), "Plant.T1.Leak", 0.3)
    ran = cli("leak", "T1", "off", "--config", CONFIG, env=env)
    assert one_line(ran.stdout) == "Plant.T1.Leak = 0 (was 0.3)"
    expect(stack.url("plant"), "Plant.T1.Leak", 0.0)


def test_valve_opening_through_the_url_flag(stack: Stack) -> None:
    ran = cli("valve", "V13", "0.5", "--config", CONFIG, "--plant-url", stack.url("plant"))
    assert ran.code == 0, ran.stderr
    assert one_line(ran.stdout) == "Plant.V13.Opening = 0.5 (was 1)"
    expect(stack.url("plant"), "Plant.V13.Opening", 0.5)
    assert cli("valve", "V13", "open", "--config", CONFIG, "--plant-url", stack.url("plant")).code == 0
    expect(stack.url("plant"), "Plant.V13.Opening", 1.0)


def test_loop_manual_at_a_percentage_then_auto(stack: Stack) -> None:
    plc = stack.url("plc")
    ran = cli("loop", "LIC1", "manual", "40", *base(stack))
    assert ran.code == 0, ran.stderr
    lines = ran.stdout.strip().splitlines()
    assert lines[0] == "PLC.LIC1.Mode = MANUAL (was AUTO)"
    assert lines[1].startswith("PLC.LIC1.ManualMV = 4.8e-05 m^3/s (40 % of 0 .. 0.00012 m^3/s)")
    expect(plc, "PLC.LIC1.Mode", int(LoopMode.MANUAL))
    expect(plc, "PLC.LIC1.ManualMV", pytest.approx(0.4 * P1_MAX, rel=1e-12))
    # The next scan drives the pump with it.
    wait_for(plc, "PLC.LIC1.MV", lambda mv: mv == pytest.approx(0.4 * P1_MAX), "MV = 40 % in MANUAL")
    ran = cli("loop", "LIC1", "auto", *base(stack))
    assert one_line(ran.stdout) == "PLC.LIC1.Mode = AUTO (was MANUAL)"
    expect(plc, "PLC.LIC1.Mode", int(LoopMode.AUTO))


def test_supervisor_mode_mpc_then_advisory(stack: Stack) -> None:
    plc = stack.url("plc")
    wait_for(plc, "PLC.Supervisor.Alive", lambda alive: alive is True, "the PLC sees the supervisor")
    ran = cli("mode", "mpc", *base(stack))
    assert ran.code == 0, ran.stderr
    assert one_line(ran.stdout) == "Supervisor.Mode = MPC (was ADVISORY)"
    expect(stack.url("supervisor"), "Supervisor.Mode", int(SupervisorMode.MPC))
    wait_for(plc, "PLC.LIC1.Mode", lambda m: m == int(LoopMode.REMOTE), "LIC1 in REMOTE under the MPC")
    ran = cli("mode", "advisory", *base(stack))
    assert one_line(ran.stdout) == "Supervisor.Mode = ADVISORY (was MPC)"
    wait_for(plc, "PLC.LIC1.Mode", lambda m: m == int(LoopMode.AUTO), "LIC1 back in AUTO")


def test_gains_show_the_applied_set_and_the_rls_state(stack: Stack) -> None:
    kp, ki, kd = read(stack.url("plc"), "PLC.LIC1.Kp", "PLC.LIC1.Ki", "PLC.LIC1.Kd")
    ran = cli("gains", "LIC1", "--json", *base(stack))
    assert ran.code == 0, ran.stderr
    doc = json.loads(ran.stdout)
    assert (doc["loop"], doc["block"], doc["gain_source"]) == ("LIC1", "pid", "FIXED")
    assert (doc["kp"], doc["ki"], doc["kd"]) == (kp, ki, kd)
    sup = doc["supervisor"]
    assert sup["reachable"] is True
    assert sup["mode"] == "ADVISORY"
    assert set(sup) >= {"theta", "covariance_trace", "accepted", "rejected", "last_reason"}
    human = cli("gains", "LIC1", *base(stack)).stdout.splitlines()
    assert human[0] == f"LIC1 (pid, AUTO): Kp = {kp:.3e}  Ki = {ki:.3e}  Kd = {kd:.3e}  from FIXED"
    assert human[1].startswith("supervisor (ADVISORY): RLS theta [")


def test_gains_set_release_and_reset_one_line_each(stack: Stack) -> None:
    plc = stack.url("plc")
    expect(plc, "PLC.LIC2.GainSource", 0)  # FIXED: the configured 10.83e-4, 3.94e-5, -13.51e-4
    ran = cli("gains", "LIC2", "--kp", "1e-3", "--ki", "3e-5", "--kd", "-1e-3", *base(stack))
    assert ran.code == 0, ran.stderr
    assert one_line(ran.stdout) == (
        "LIC2: SetGains(Kp = 1.000e-03, Ki = 3.000e-05, Kd = -1.000e-03) from the next scan on, "
        "GainSource ENGINEER (was FIXED); the supervisor is kept off until `tankctl gains LIC2 "
        "--release` or `--reset`"
    )
    expect(plc, "PLC.LIC2.GainSource", 3)  # ENGINEER
    assert read(plc, "PLC.LIC2.Kp", "PLC.LIC2.Ki", "PLC.LIC2.Kd") == [1e-3, 3e-5, -1e-3]
    # Out of the gain box: refused whole, exit 1, one line; an omitted gain is the applied one.
    ran = cli("gains", "LIC2", "--kp", "1.0", *base(stack))
    assert ran.code == 1 and ran.stdout == ""
    assert one_line(ran.stderr) == (
        "tankctl: PLC.LIC2.SetGains(1, 3e-05, -0.001) refused: BadOutOfRange "
        "(a gain is not finite or lies outside the loop's gain box)"
    )
    assert read(plc, "PLC.LIC2.Kp") == [1e-3]
    # An Observer may not reset.
    env = {"TANKLAB_USER": "observer", "TANKLAB_PASSWORD": TEST_PASSWORDS["observer"]}
    ran = proc("gains", "LIC2", "--reset", *base(stack), env=env)
    assert ran.code == 1
    assert one_line(ran.stderr) == (
        "tankctl: PLC.LIC2.ResetGains() refused: BadUserAccessDenied (your role may not do this)"
    )
    # Release: the gains stay, GainSource FIXED.
    ran = cli("gains", "LIC2", "--release", *base(stack))
    assert ran.code == 0, ran.stderr
    assert one_line(ran.stdout) == (
        "LIC2: ReleaseGains: back under adaptation, gains kept (Kp = 1.000e-03 Ki = 3.000e-05 "
        "Kd = -1.000e-03), GainSource FIXED until the supervisor pushes"
    )
    expect(plc, "PLC.LIC2.GainSource", 0)
    assert read(plc, "PLC.LIC2.Kp") == [1e-3]
    ran = cli("gains", "LIC2", "--release", *base(stack))
    assert one_line(ran.stdout) == "LIC2: ReleaseGains: not held by an engineer (GainSource FIXED), no change"
    # Reset: the configured gains at the next scan.
    ran = cli("gains", "LIC2", "--reset", *base(stack))
    assert ran.code == 0, ran.stderr
    assert one_line(ran.stdout) == (
        "LIC2: ResetGains: the configured gains from the next scan on, GainSource FIXED "
        "(was FIXED: Kp = 1.000e-03 Ki = 3.000e-05 Kd = -1.000e-03)"
    )
    expect(plc, "PLC.LIC2.Kp", 10.83e-4)
    assert read(plc, "PLC.LIC2.Ki", "PLC.LIC2.Kd", "PLC.LIC2.GainSource") == [3.94e-5, -13.51e-4, 0]
    # Bad usage: one line, exit 2, nothing sent.
    ran = cli("gains", "LIC2", "--reset", "--release", *base(stack))
    assert ran.code == 2
    assert one_line(ran.stderr) == "tankctl: give one of --kp/--ki/--kd, --reset and --release"


def test_status_json_has_the_documented_shape(stack: Stack) -> None:
    ran = cli("status", "--json", *base(stack))
    assert ran.code == 0, ran.stderr
    doc = json.loads(ran.stdout)
    assert set(doc) == {"site", "config_digest", "plant", "plc", "supervisor"}
    assert doc["site"] == "three_tank_energies_sim"
    assert doc["config_digest"] == ENERGIES.digest
    plant, plc, sup = doc["plant"], doc["plc"], doc["supervisor"]
    assert all(d["reachable"] is True for d in (plant, plc, sup))
    assert plant["url"] == stack.url("plant")
    assert set(plant["tanks"]) == {"T1", "T2", "T3"}
    assert set(plant["tanks"]["T1"]) == {
        "level_m",
        "lt_pv_m",
        "lt_fault",
        "lt_fault_value",
        "leak",
        "disturbance_m3_s",
        "lsh",
        "lsl",
    }
    assert set(plant["valves"]) == {"V13", "V32", "V20"}
    assert plant["pumps"]["P1"]["unit"] == "m^3/s"
    assert plant["model_time_s"] > 0 and plant["speed"] == 20.0
    lic1 = plc["loops"]["LIC1"]
    assert set(lic1) == {
        "block",
        "mode",
        "sp_m",
        "pv_m",
        "mv",
        "mv_unit",
        "mv_percent",
        "manual_mv",
        "kp",
        "ki",
        "kd",
        "gain_source",
    }
    assert (lic1["sp_m"], lic1["mv_unit"], lic1["gain_source"]) == (0.4, "m^3/s", "FIXED")
    assert 0 <= lic1["mv_percent"] <= 100
    assert isinstance(plc["scan"], int) and plc["io_healthy"] is True
    assert set(plc["io"]) == {"LT1", "LT2", "LT3"}
    assert "T1HH" in plc["alarms"] and "SupervisorLost" in plc["alarms"]
    assert set(plc["interlocks"]) == {"T1HH", "T2HH"}
    assert isinstance(plc["active_alarms"], list) and isinstance(plc["tripped"], list)
    assert sup["mode"] == "ADVISORY" and sup["mpc"]["horizon"] == 10
    summary_keys = {"active", "unacknowledged", "shelved", "suppressed", "disabled"}
    summary_keys |= {"rate_per_10min", "peak_rate_per_10min", "flood"}
    for tier in (plc, sup):
        s = tier["alarm_summary"]
        assert set(s) == summary_keys
        assert all(type(s[k]) is int for k in summary_keys - {"flood"}) and s["flood"] is False
        assert s["disabled"] == 0 and s["shelved"] == 0  # nobody disabled or shelved one
    human = cli("status", *base(stack))
    assert human.code == 0
    for word in (
        "three_tank_energies_sim",
        "T1",
        "T3",
        "LIC1",
        "PLC alarms:",
        "supervisor alarms:",
        "model time",
    ):
        assert word in human.stdout


def test_status_with_a_tier_down_and_with_nothing_up(stack: Stack) -> None:
    gone = f"opc.tcp://127.0.0.1:{free_port()}/tanklab/supervisor"
    ran = cli("status", "--json", *base(stack), "--supervisor-url", gone)
    assert ran.code == 0  # the PLC answers
    doc = json.loads(ran.stdout)
    assert doc["supervisor"] == {"reachable": False, "url": gone, "error": "connection refused"}
    assert doc["plc"]["reachable"] is True
    nothing = proc("status", "--config", CONFIG, "--base-port", str(free_base_port()))
    assert nothing.code == 2
    assert one_line(nothing.stderr).startswith("tankctl: cannot reach plc at opc.tcp://127.0.0.1:")
    assert "UNREACHABLE: connection refused" in nothing.stdout
    # Without a config nothing says which site it is: each tier and why, no site.
    port = free_base_port()
    nothing = proc("status", "--base-port", str(port), env={"TANKLAB_CONFIG": ""})
    assert nothing.code == 2
    assert one_line(nothing.stderr) == (
        f"tankctl: cannot reach plc at opc.tcp://127.0.0.1:{port + 1}/tanklab/plc: connection refused"
    )
    urls = [f"opc.tcp://127.0.0.1:{port + k}/tanklab/{t}" for k, t in enumerate(TIERS)]
    width = max(map(len, urls))
    assert nothing.stdout.splitlines() == ["site unknown: no tier answered"] + [
        f"{t:<11}{url:<{width}}  UNREACHABLE: connection refused" for t, url in zip(TIERS, urls, strict=True)
    ]


def _find(nodes: list[dict[str, Any]], path: str) -> dict[str, Any]:
    for n in nodes:
        if n["path"] == path:
            return n
        found = _find(n.get("children", []), path) if path.startswith(n["path"] + ".") else None
        if found:
            return found
    return {}


def test_browse_plc_json_is_the_servers_tree_with_units_and_ranges(stack: Stack) -> None:
    ran = cli("browse", "plc", "--json", *base(stack))
    assert ran.code == 0, ran.stderr
    doc = json.loads(ran.stdout)
    assert set(doc) == {"plc"}
    nodes = doc["plc"]["nodes"]
    assert [n["name"] for n in nodes] == ["PLC"]  # only the tanklab namespace under Objects
    sp = _find(nodes, "PLC.LIC1.SP")
    assert sp["class"] == "Variable"
    assert (sp["unit"], sp["eu_range"], sp["writable"], sp["data_type"]) == ("m", [0.0, 0.6], True, "Double")
    assert sp["value"] == 0.4
    mode = _find(nodes, "PLC.LIC1.Mode")
    assert mode["enum_strings"] == ["MANUAL", "AUTO", "REMOTE"] and mode["enum"] == "AUTO"
    assert _find(nodes, "PLC.LIC1.Kp")["writable"] is False
    assert _find(nodes, "PLC.LIC1.SetGains")["inputs"] == ["Kp", "Ki", "Kd"]
    human = cli("browse", "plc", *base(stack))
    assert human.code == 0
    assert "SetGains()" in human.stdout and "0 .. 0.6" in human.stdout


def test_watch_for_a_duration_prints_every_tank(stack: Stack) -> None:
    ran = proc("watch", "--duration", "2", "--interval", "0.5", *base(stack))
    assert ran.code == 0, ran.stderr
    lines = ran.stdout.strip().splitlines()
    assert len(lines) >= 2
    for line in lines:
        assert line.startswith("t=")
        for tank in ("T1 ", "T2 ", "T3 "):
            assert tank in line
    # On a terminal (forced here): the live table.
    live = cli("watch", "--duration", "1", "--interval", "0.5", *base(stack), env={"FORCE_COLOR": "1"})
    assert live.code == 0
    assert "tanklab watch: three_tank_energies_sim" in live.stdout
    assert "LIC1 AUTO" in live.stdout


def test_scenario_run_applies_its_events_in_order_on_model_time(stack: Stack, tmp_path: Path) -> None:
    scenario = tmp_path / "two_events.yaml"
    scenario.write_text(
        f"name: two_events\nsite: {CONFIG}\nduration_s: 20\n"
        "events:\n"
        "  - {at_s: 6, kind: leak, tank: T1, opening: 0.1}\n"
        "  - {at_s: 2, kind: setpoint, loop: LIC1, value_m: 0.43}\n"
    )
    (t_before,) = read(stack.url("plant"), "Plant.Sim.Time")
    ran = proc("scenario", "run", str(scenario), "--base-port", str(stack.base))
    assert ran.code == 0, ran.stderr
    lines = ran.stdout.strip().splitlines()
    applied = [line for line in lines if line.startswith("t=")]
    assert len(applied) == 2
    assert "@2 s setpoint LIC1 0.43 m: PLC.LIC1.SP = 0.43 m" in applied[0]
    assert "@6 s leak T1 0.1: Plant.T1.Leak = 0.1" in applied[1]
    times = [float(re.match(r"t=\s*([0-9.]+) s", line)[1]) for line in applied]  # type: ignore[index]
    assert 2.0 <= times[0] <= times[1] and times[1] >= 6.0
    assert lines[-1] == "done: 2 of 2 events applied"
    expect(stack.url("plc"), "PLC.LIC1.SP", 0.43)
    expect(stack.url("plant"), "Plant.T1.Leak", 0.1)
    (t_after,) = read(stack.url("plant"), "Plant.Sim.Time")
    assert t_after - t_before >= 6.0  # the run took at least the last event's model time
    assert cli("setpoint", "LIC1", "0.4", *base(stack)).code == 0
    assert cli("leak", "T1", "off", *base(stack)).code == 0


def test_unreachable_endpoint_is_one_line_naming_it_and_exit_2() -> None:
    url = f"opc.tcp://127.0.0.1:{free_port()}/tanklab/plc"
    ran = proc("setpoint", "LIC1", "0.4", "--config", CONFIG, "--plc-url", url)
    assert ran.code == 2
    assert one_line(ran.stderr) == f"tankctl: cannot reach plc at {url}: connection refused"
    assert ran.stdout == ""


# --------------------------------------------------------------------------------------------
# Site identity (#21 item 5): the commands check which site they talk to
# --------------------------------------------------------------------------------------------


def test_a_config_of_another_site_is_refused_in_one_line(stack: Stack) -> None:
    two = SiteIdentity.of(load_site(ROOT / TWO_TANK))
    ran = proc("status", "--config", TWO_TANK, "--base-port", str(stack.base))
    assert ran.code == 2
    # status asks the tiers at once: the first to answer is named.
    tier = re.match(r"tankctl: site mismatch: (plant|plc|supervisor) at ", one_line(ran.stderr))
    assert tier is not None, ran.stderr
    assert one_line(ran.stderr) == (
        f"tankctl: site mismatch: {tier[1]} at {stack.url(tier[1])} runs three_tank_energies_sim (config "
        f"{ENERGIES.short}); --config {TWO_TANK} is two_tank_interacting (config {two.short}); give the "
        "stack's config, or no --config to take the site from the stack"
    )
    assert ran.stdout == ""  # no two-tank status with wrong percentages
    (before,) = read(stack.url("plc"), "PLC.LIC1.SP")
    ran = cli("setpoint", "LIC1", "0.3", "--config", TWO_TANK, "--base-port", str(stack.base))
    assert ran.code == 2 and "site mismatch" in one_line(ran.stderr)
    assert read(stack.url("plc"), "PLC.LIC1.SP") == [before]  # nothing written
    # The same site with one parameter changed is another config: refused as well.
    edited = load_site(CONFIG).model_dump(mode="json")
    edited["plc"]["loops"][0]["setpoint_m"] = 0.3
    changed = ROOT / "var" / f"edited-{stack.base}.json"
    changed.parent.mkdir(exist_ok=True)
    try:
        changed.write_text(json.dumps(edited))
        ran = cli("leak", "T1", "0", "--config", str(changed), "--base-port", str(stack.base))
        assert ran.code == 2
        assert f"runs three_tank_energies_sim (config {ENERGIES.short}); --config" in one_line(ran.stderr)
    finally:
        changed.unlink()


def test_without_a_config_the_site_is_the_stacks(stack: Stack) -> None:
    # No --config and no TANKLAB_CONFIG: the site is the one the stack publishes.
    env = {"TANKLAB_CONFIG": ""}
    ran = cli("status", "--json", "--base-port", str(stack.base), env=env)
    assert ran.code == 0, ran.stderr
    doc = json.loads(ran.stdout)
    assert (doc["site"], doc["config_digest"]) == (ENERGIES.name, ENERGIES.digest)
    assert set(doc["plant"]["tanks"]) == {"T1", "T2", "T3"}
    human = cli("status", "--base-port", str(stack.base), env=env)
    assert human.stdout.splitlines()[0] == (
        f"three_tank_energies_sim  config {ENERGIES.short} (from plc at {stack.url('plc')})"
    )
    ran = cli("valve", "V32", "0.9", "--base-port", str(stack.base), env=env)
    assert ran.code == 0, ran.stderr
    assert one_line(ran.stdout) == "Plant.V32.Opening = 0.9 (was 1)"
    assert cli("valve", "V32", "open", "--base-port", str(stack.base), env=env).code == 0
    ran = cli("setpoint", "LIC9", "0.4", "--base-port", str(stack.base), env=env)  # names from the stack
    assert ran.code == 2
    assert one_line(ran.stderr) == (
        "tankctl: unknown loop 'LIC9' (the site three_tank_energies_sim has LIC1, LIC2)"
    )


def test_a_scenario_for_another_site_is_refused_naming_why(stack: Stack) -> None:
    kortela = SiteIdentity.of(load_site(ROOT / "configs/three_tank_kortela.yaml"))
    ran = proc("scenario", "run", "configs/scenarios/kortela_mpc_vs_pi.yaml", "--base-port", str(stack.base))
    assert ran.code == 2
    assert one_line(ran.stderr) == (
        f"tankctl: scenario kortela_mpc_vs_pi is written for three_tank_kortela (config {kortela.short}) "
        f"(site: ../three_tank_kortela.yaml), but the stack runs three_tank_energies_sim (config "
        f"{ENERGIES.short}) (plant at {stack.url('plant')})"
    )
    assert ran.stdout == ""


def test_a_scenario_with_fields_a_live_stack_cannot_take(stack: Stack, tmp_path: Path) -> None:
    scenario = tmp_path / "with_variant.yaml"
    scenario.write_text(
        f"name: with_variant\nsite: {CONFIG}\nduration_s: 5\n"
        "initial: {levels_m: [0.1, 0.1, 0.1]}\n"
        "events: [{at_s: 0, kind: leak, tank: T2, opening: 0.05}]\n"
        "variants: [{name: tuned, set: {plc.loops.0.gains.kp: 0.002}}]\n"
    )
    fields = [
        "initial.levels_m (a running plant's levels are not writable)",
        "variants[tuned].set plc.loops.0.gains.kp (a running stack's site is fixed at its start)",
    ]
    ran = cli("scenario", "run", str(scenario), "--base-port", str(stack.base))
    assert ran.code == 2
    assert one_line(ran.stderr) == (
        "tankctl: scenario with_variant: 2 fields cannot be applied to a running stack: "
        f"{'; '.join(fields)}; --ignore-unappliable runs its events without them"
    )
    assert ran.stdout == ""
    assert read(stack.url("plant"), "Plant.T2.Leak") == [0.0]  # refused before any write
    ran = cli("scenario", "run", str(scenario), "--ignore-unappliable", "--base-port", str(stack.base))
    assert ran.code == 0, ran.stderr
    lines = ran.stdout.strip().splitlines()
    assert [line for line in lines if line.startswith("not applied: ")] == [
        f"not applied: {f}" for f in fields
    ]
    assert "@0 s leak T2 0.05: Plant.T2.Leak = 0.05 (was 0)" in ran.stdout
    assert lines[-1] == "done: 1 of 1 events applied"
    assert cli("leak", "T2", "off", *base(stack)).code == 0
