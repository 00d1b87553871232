"""The supervisory-controller plug-in (decision 0054): a user's class loaded by dotted path runs
in the co-simulation through the same host as in the supervisor process; what it does wrong is
contained (no bad value written, counted, heartbeat withheld after repeated failures so the PLC's
watchdog sheds the loops); bad dotted paths are one-line errors.

The user's package is ``tests/fixtures/user_ctrl`` (outside ``src/``), put on the path as a user's
would be. Overruns are measured on a fake CPU clock the test's controller advances.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from helpers import ROOT
from supervisor.controller import ControllerOutput, ShippedController, build_controller, load_controller_class
from supervisor.cycle import PlcSnapshot, SupervisorCore
from supervisor.host import ControllerHost, build_host
from tankctl.cli import app
from tankctl.cosim import CoSimulation
from tanklab.config import SiteConfig, load_site
from tanklab.enums import GainSource, LoopMode
from tanklab.errors import ConfigError, ControllerError
from tanklab.tags import DataType, supervisor_tags, tags_by_path

FIXTURES = ROOT / "tests" / "fixtures"
PARAMS = {"kp": 5e-4, "ki": 1e-5, "u_ff": {"LIC1": 2e-5, "LIC2": 1e-5}}


@pytest.fixture(autouse=True)
def user_path(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(FIXTURES))


def site_file(tmp_path: Path, controller: Mapping[str, Any] | None = None) -> Path:
    """The Energies three-tank site, tanks part-filled, with ``supervisor.controller``."""
    data = yaml.safe_load((ROOT / "configs" / "three_tank_energies_sim.yaml").read_text())
    for i, level in enumerate((0.36, 0.17, 0.27)):
        data["plant"]["tanks"][i]["initial_level_m"] = level
    if controller is not None:
        data["supervisor"]["controller"] = dict(controller)
    path = tmp_path / "site.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def site_with(tmp_path: Path, cls: str, **extra: Any) -> SiteConfig:
    return load_site(site_file(tmp_path, {"class": cls, "params": extra.pop("params", PARAMS), **extra}))


def snapshot(sp: list[float], pv: list[float], modes: tuple[LoopMode, ...]) -> PlcSnapshot:
    n = len(sp)
    return PlcSnapshot(
        scan=1,
        t_s=1.0,
        sp_m=np.array(sp),
        pv_m=np.array(pv),
        mv=np.zeros(n),
        modes=modes,
        gains=np.zeros((n, 3)),
        levels_m=np.array([pv[0], pv[1], 0.27]),
        good=np.ones(3, dtype=bool),
        sources=(GainSource.FIXED,) * n,
    )


class FakeCpu:
    """CPU seconds that only the controller under test advances."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_the_first_action_matches_the_hand_computed_pi_with_feedforward(tmp_path: Path) -> None:
    site = site_with(tmp_path, "user_ctrl.pi_ff:PiFeedforward")
    _, host = build_host(site, cpu_clock=FakeCpu())
    act = host.cycle(snapshot([0.4, 0.2], [0.35, 0.22], (LoopMode.AUTO, LoopMode.AUTO)))
    # LIC1: e = 0.05 m, I = 0.05 m s (Ts = 1 s): u = 2e-5 + 5e-4 * 0.05 + 1e-5 * 0.05 = 4.55e-5 m^3/s
    # LIC2: e = -0.02 m: raw = 1e-5 - 1e-5 - 2e-7 = -2e-7 < 0 = command_min: u = 0, I held at 0
    assert act.remote_mv == {"LIC1": pytest.approx(4.55e-5, rel=1e-12), "LIC2": 0.0}
    assert act.modes == {"LIC1": LoopMode.REMOTE, "LIC2": LoopMode.REMOTE}
    assert act.gains == {}
    rep = host.report()
    assert rep.class_name == "user_ctrl.pi_ff:PiFeedforward"
    assert (rep.cycles, rep.errors, rep.overruns, rep.last_error) == (1, 0, 0, "")
    assert rep.diagnostics == {
        "Error": pytest.approx(0.05),
        "Integral": pytest.approx(0.05),
        "Saturated": True,
        "Phase": "entering",
    }
    assert host.controller.integral["LIC2"] == 0.0  # anti-windup


def test_a_dotted_path_drives_the_cosimulation_in_remote(tmp_path: Path) -> None:
    site = load_site(site_file(tmp_path))
    sim = CoSimulation(site, controller="user_ctrl.pi_ff:PiFeedforward")
    tr = sim.run(300.0)
    assert sim.host is not None and sim.host.class_name == "user_ctrl.pi_ff:PiFeedforward"
    assert tr.array("modes")[-1].tolist() == [float(LoopMode.REMOTE)] * 2
    rep = sim.host.report()
    assert (rep.cycles, rep.errors, rep.overruns) == (300, 0, 0)
    # the default params (no feedforward) still bring T1 from 0.36 m up toward its 0.4 m SP
    assert tr.array("levels_m")[-1, 0] > 0.38
    assert sim.heartbeat == 300  # every scan acknowledged


def test_config_params_reach_the_class_and_match_the_cli_path(tmp_path: Path) -> None:
    site = site_with(tmp_path, "user_ctrl.pi_ff:PiFeedforward")
    a = CoSimulation(site, supervisor_mode="ADVISORY")  # the config's class
    b = CoSimulation(load_site(site_file(tmp_path)), controller=build_controller(site))
    for sim in (a, b):
        sim.run(40.0)
    np.testing.assert_array_equal(a.trace.array("commands"), b.trace.array("commands"))
    assert a.host is not None and a.host.controller.u_ff == {"LIC1": 2e-5, "LIC2": 1e-5}


@pytest.mark.parametrize(
    ("cls", "kind"), [("user_ctrl.pi_ff:RaisesAfter", "raised"), ("user_ctrl.pi_ff:NanAfter", "non_finite")]
)
def test_a_failing_controller_is_contained_and_the_watchdog_sheds_the_loops(
    tmp_path: Path, cls: str, kind: str
) -> None:
    site = site_with(tmp_path, cls, params={**PARAMS, "good_steps": 5}, max_failures=3)
    sim = CoSimulation(site, supervisor_mode="ADVISORY")
    host = sim.host
    assert host is not None
    sim.run(5.0)  # five good steps (one per 1 s scan): the loops are in REMOTE
    held = [sim.plc.loop(lp).remote_mv for lp in ("LIC1", "LIC2")]
    assert [sim.plc.loop(lp).mode for lp in ("LIC1", "LIC2")] == [LoopMode.REMOTE] * 2
    beats = sim.heartbeat
    sim.run(2.0)  # two failed steps: counted, nothing written, the heartbeat still goes on
    assert (host.errors, host.failing) == (2, False)
    assert host.last_error.startswith(f"{kind}: ")
    assert [sim.plc.loop(lp).remote_mv for lp in ("LIC1", "LIC2")] == held  # last safe action held
    assert all(math.isfinite(v) for v in held)
    assert sim.heartbeat == beats + 2
    sim.run(1.0)  # the third in a row: failing, the heartbeat is withheld from now on
    assert host.failing and sim.heartbeat == beats + 2
    sim.run(5.0)  # the PLC's 3 s watchdog expires: REMOTE falls back to AUTO, as for a lost supervisor
    assert not sim.plc.watchdog.alive
    assert [sim.plc.loop(lp).mode for lp in ("LIC1", "LIC2")] == [LoopMode.AUTO] * 2
    assert host.errors == 8 and host.report().errors == 8
    assert host.overruns == 0


class SlowAfter:
    """A PI+FF that, from its fourth step on, uses 2 s of (fake) CPU time per step."""

    def __init__(self, site: SiteConfig, cpu: FakeCpu) -> None:
        from user_ctrl.pi_ff import PiFeedforward

        self.inner = PiFeedforward(site, PARAMS)
        self.diagnostics = PiFeedforward.diagnostics
        self.cpu = cpu
        self.calls = 0

    def step(self, snapshot: PlcSnapshot, t_s: float) -> ControllerOutput:
        self.calls += 1
        self.cpu.t += 2.0 if self.calls > 3 else 0.01
        return self.inner.step(snapshot, t_s)


def test_an_overrun_is_discarded_counted_and_sheds_after_max_failures(tmp_path: Path) -> None:
    site = load_site(site_file(tmp_path, {"class": "user_ctrl.pi_ff:PiFeedforward", "budget_s": 0.5}))
    cpu = FakeCpu()
    slow = SlowAfter(site, cpu)
    sim = CoSimulation(site, controller=slow, cpu_clock=cpu)  # type: ignore[arg-type]
    host = sim.host
    assert host is not None and host.budget_s == 0.5
    sim.run(3.0)  # three quick steps
    held = sim.plc.loop("LIC1").remote_mv
    sim.run(1.0)
    assert (host.overruns, host.errors) == (1, 0)
    assert host.last_error == "overrun: step took 2 s of CPU time, budget 0.5 s"
    assert sim.plc.loop("LIC1").remote_mv == held
    sim.run(10.0)
    assert host.failing and host.overruns == 11
    assert sim.plc.loop("LIC1").mode is LoopMode.AUTO  # the watchdog shed it


def test_out_of_range_and_malformed_outputs_are_contained(tmp_path: Path) -> None:
    site = site_with(tmp_path, "user_ctrl.pi_ff:PiFeedforward")
    cases: list[tuple[ControllerOutput, str]] = [
        (ControllerOutput(remote_mv={"LIC1": 1.0}), "out_of_range: LIC1 RemoteMV 1 outside [0, 0.00012]"),
        (ControllerOutput(remote_mv={"LIC9": 0.0}), "bad_output: RemoteMV for unknown loop 'LIC9'"),
        (ControllerOutput(gains={"LIC1": (1.0, 0.0, 0.0)}), "out_of_range: LIC1 gains (1, 0, 0) outside"),
        (ControllerOutput(gains={"LIC1": (math.inf, 0.0, 0.0)}), "non_finite: LIC1 gains"),
        (ControllerOutput(modes={"LIC1": LoopMode.MANUAL}), "bad_output: LIC1 mode"),
        (ControllerOutput(diagnostics={"Nope": 1.0}), "bad_output: diagnostic 'Nope' not declared"),
        (ControllerOutput(diagnostics={"Phase": 3.0}), "bad_output: diagnostic Phase = 3.0: declared str"),
        (ControllerOutput(diagnostics={"Error": math.nan}), "non_finite: diagnostic Error"),
    ]

    class Scripted:
        diagnostics = load_controller_class("user_ctrl.pi_ff:PiFeedforward").diagnostics

        def __init__(self) -> None:
            self.out: Any = None

        def step(self, snapshot: PlcSnapshot, t_s: float) -> Any:
            return self.out

    ctl = Scripted()
    _, host = build_host(site, controller=ctl, cpu_clock=FakeCpu())  # type: ignore[arg-type]
    host.max_failures = 100
    snap = snapshot([0.4, 0.2], [0.35, 0.22], (LoopMode.REMOTE, LoopMode.REMOTE))
    for k, (out, message) in enumerate(cases, start=1):
        ctl.out = out
        act = host.cycle(snap)
        assert (act.remote_mv, act.modes, act.gains) == ({}, {}, {})
        assert host.last_error.startswith(message), host.last_error
        assert host.errors == k
    ctl.out = "not an output"
    host.cycle(snap)
    assert host.last_error == "bad_output: step returned str, not ControllerOutput"
    # a RemoteMV for a loop left out of REMOTE is not written (nor an error)
    ctl.out = ControllerOutput(remote_mv={"LIC1": 1e-5})
    act = host.cycle(snapshot([0.4, 0.2], [0.35, 0.22], (LoopMode.AUTO, LoopMode.AUTO)))
    assert act.remote_mv == {} and host.consecutive == 0


def test_bad_dotted_paths_are_one_line_errors_naming_the_problem(tmp_path: Path) -> None:
    cases = {
        "nosuch_pkg.mod:Ctl": "module 'nosuch_pkg.mod' is not importable",
        "user_ctrl.pi_ff:Missing": "module 'user_ctrl.pi_ff' has no attribute 'Missing'",
        "user_ctrl.pi_ff:NoStep": "does not implement SupervisoryController",
        "user_ctrl.broken:Ctl": "importing 'user_ctrl.broken' raised RuntimeError: this module is broken",
        "user_ctrl.pi_ff:math": "'math' is a module, not a class",
    }
    for path, message in cases.items():
        with pytest.raises(ControllerError) as err:
            load_controller_class(path)
        assert str(err.value).startswith(f"controller {path}: {message}") and "\n" not in str(err.value)
    with pytest.raises(
        ControllerError, match=r"^controller 'no-colon': not a dotted path package.module:Class$"
    ):
        load_controller_class("no-colon")
    site = load_site(site_file(tmp_path))
    with pytest.raises(ControllerError, match=r"^--controller: controller user_ctrl.pi_ff:NoStep: does not"):
        build_controller(site, "user_ctrl.pi_ff:NoStep")
    bad = site_with(tmp_path, "user_ctrl.pi_ff:PiFeedforward", params={"gain": 1})
    with pytest.raises(ControllerError, match=r"construction failed .*: ValueError: unknown params gain$"):
        build_controller(bad)
    with pytest.raises(ValueError, match="takes no params"):
        ShippedController(site, {"x": 1})


def test_a_malformed_config_path_names_the_file_field_and_rule(tmp_path: Path) -> None:
    path = site_file(tmp_path, {"class": "not a path"})
    with pytest.raises(ConfigError) as err:
        load_site(path)
    msg = str(err.value)
    assert msg.startswith(str(path)) and "supervisor.controller.class" in msg and "pattern" in msg
    bad = site_file(tmp_path, {"class": "user_ctrl.pi_ff:NoStep"})
    result = CliRunner().invoke(
        app, ["simulate", str(ROOT / "configs/scenarios/energies_mpc_pid_vs_pid.yaml"), "-c", str(bad)]
    )
    assert result.exit_code == 2
    assert result.stderr.strip() == (
        f"tankctl: {bad}: supervisor.controller.class: controller user_ctrl.pi_ff:NoStep: "
        "does not implement SupervisoryController (no step(snapshot, t_s) method)"
    )


@pytest.mark.parametrize("command", ["simulate", "supervisor"])
def test_the_cli_refuses_an_unknown_controller_in_one_line(tmp_path: Path, command: str) -> None:
    cfg = site_file(tmp_path)
    args = {
        "simulate": [
            "simulate",
            str(ROOT / "configs/scenarios/energies_mpc_pid_vs_pid.yaml"),
            "-c",
            str(cfg),
        ],
        "supervisor": ["supervisor", "--config", str(cfg), "--port", "1"],
    }[command]
    result = CliRunner().invoke(app, [*args, "--controller", "nosuch_pkg.mod:Ctl"])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(
        "tankctl: --controller: controller nosuch_pkg.mod:Ctl: module 'nosuch_pkg.mod'"
    )


def test_declared_diagnostics_become_supervisor_controller_nodes(tmp_path: Path) -> None:
    site = load_site(site_file(tmp_path))
    cls = load_controller_class("user_ctrl.pi_ff:PiFeedforward")
    tags = tags_by_path(supervisor_tags(site, cls.diagnostics))
    for name in ("Class", "Cycles", "Errors", "LastError", "Overruns"):
        assert f"Supervisor.Controller.{name}" in tags
    err = tags["Supervisor.Controller.Diagnostics.Error"]
    assert err.analog and err.unit == "m"
    assert tags["Supervisor.Controller.Diagnostics.Saturated"].data_type == DataType.BOOLEAN
    assert tags["Supervisor.Controller.Diagnostics.Phase"].data_type == DataType.STRING
    assert not any(
        p.startswith("Supervisor.Controller.Diagnostics") for p in tags_by_path(supervisor_tags(site))
    )


def test_the_shipped_controller_through_the_host_is_the_core_itself(tmp_path: Path) -> None:
    site = load_site(site_file(tmp_path))
    core, host = build_host(site)
    assert isinstance(host.controller, ShippedController) and host.controller.core is core
    assert isinstance(host, ControllerHost) and host.class_name == "supervisor.controller:ShippedController"


@functools.cache
def _shared(tmp: str) -> tuple[SiteConfig, SupervisorCore]:
    site = load_site(site_file(Path(tmp)))
    return site, SupervisorCore(site)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    mv=st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=2, max_size=2),
    remote=st.lists(st.booleans(), min_size=2, max_size=2),
)
def test_whatever_a_controller_returns_only_in_range_values_are_written(
    tmp_path_factory: pytest.TempPathFactory, mv: list[float], remote: list[bool]
) -> None:
    site, core = _shared(str(tmp_path_factory.getbasetemp()))

    class Fixed:
        diagnostics = ()

        def step(self, snapshot: PlcSnapshot, t_s: float) -> ControllerOutput:
            return ControllerOutput(remote_mv={"LIC1": mv[0], "LIC2": mv[1]})

    host = ControllerHost(site, Fixed(), core, cpu_clock=FakeCpu())  # type: ignore[arg-type]
    modes = tuple(LoopMode.REMOTE if r else LoopMode.AUTO for r in remote)
    act = host.cycle(snapshot([0.4, 0.2], [0.35, 0.22], modes))
    ok = all(math.isfinite(v) and 0.0 <= v <= 1.2e-4 for v in mv)
    if ok:
        assert act.remote_mv == {lp: v for lp, v, r in zip(("LIC1", "LIC2"), mv, remote, strict=True) if r}
        assert host.errors == 0
    else:
        assert act.remote_mv == {} and host.errors == 1  # whole output refused, nothing written
