"""tanklab's pytest plugin: fixtures to test one's own controller against the tanklab models.

Registered through the ``pytest11`` entry point ``tanklab``, so any pytest run in an environment
where tanklab is installed has these fixtures (``pytest -p no:tanklab`` turns it off):

``tanklab_config``
    Path of the site config the tests use: the ``tanklab_site`` marker's ``config``, else
    ``--tanklab-config PATH``, else the ini option ``tanklab_config`` (relative to the ini file's
    directory), else the environment's ``TANKLAB_CONFIG``. A test without any of them fails with
    one line saying how to give one.
``tanklab_site_overrides``
    Dotted paths into the site file mapped to new values, exactly as a scenario variant's
    ``set:`` (``{"plc.loops.0.gains.kp": 2.1e-3}``): the marker's ``overrides``, else none.
    Override the fixture in a ``conftest.py`` to change it for a directory.
``tanklab_site``
    The validated :class:`~tanklab.config.SiteConfig` of that file with those overrides (a
    broken config fails the test with the config error's one line: file, field, rule).
``tanklab_cosim``
    A fresh in-process co-simulation (:class:`tankctl.cosim.CoSimulation`) of ``tanklab_site``:
    the plant and the PLC program on a virtual clock, with the supervisor in the marker's
    ``supervisor_mode`` (OFF / ADVISORY / ADAPTIVE_PID / MPC) when the site has one.
``tanklab_scenario``
    Runs a scenario file in the co-simulation, as ``tankctl simulate`` does, and returns a
    :class:`ScenarioRun`: its result (trajectories and metrics per variant) and
    ``assert_expectations()``, which fails the test with one line per unmet ``expect:`` bound
    (as ``tankctl scenario check`` prints them).

``tanklab_stack``
    The site's real tiers, each a ``python -m tankctl`` process on free loopback ports: plant,
    PLC, the supervisor when the site has one, and the historian when asked for, secured by a
    throw-away PKI with one user per login role (``observer``, ``operator``, ``engineer``,
    random passwords; :func:`tanklab_logins`). A
    :class:`~tankctl.testing.fixture.RunningStack`: ``stack.plc`` / ``stack.plant`` /
    ``stack.supervisor`` are synchronous clients logged in as the stack's role, with
    ``read(path)``, ``read_many(paths)``, ``write(path, value)`` (typed from the tag contract; a
    refused write raises one line naming the status) and ``call(method_path, *args)``;
    ``stack.client(tier, role)`` is one as another role; ``stack.advance(model_s)`` waits
    (bounded) until the PLC's model time has moved on by that much. In an ``async`` test,
    ``async with stack.connect("plc", role) as plc:`` gives the same calls awaited in the test's
    own event loop (``plc.client`` is the asyncua client). Every process is stopped after the
    test on every path, a failed or interrupted one too (an ``atexit`` hook kills, by id, what
    an interrupted run left). Lock-step by default: model time runs as fast as the processes go
    and the PLC waits for the supervisor's acknowledgement of each scan (``clock="realtime"``:
    the wall clock times ``speed``).
``tanklab_stack_factory``
    ``start(clock=None, speed=None, historian=None, role=None) -> RunningStack``: a stack with
    options (the marker's, else ``--tanklab-clock``, else lock-step; speed 1; no historian;
    role ``operator``), as many as a test needs, all stopped after it.
``tanklab_logins``
    The session's throw-away security home and its users' passwords
    (:class:`~tankctl.testing.logins.Logins`): provisioned once per test session.

Markers: ``@pytest.mark.tanklab_site(config=PATH, overrides={...}, supervisor_mode="MPC")`` and
``@pytest.mark.tanklab_stack(clock="lockstep" | "realtime", speed=..., historian=False,
role="operator")``.

The co-simulation, the numerics and the stack machinery are imported when a fixture is first
used, not when pytest loads the plugin, so a test run that does not use them pays nothing.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from tankctl.cosim import CoSimulation
    from tankctl.simulate import ScenarioResult
    from tankctl.testing.fixture import RunningStack
    from tankctl.testing.logins import Logins
    from tanklab.config import SiteConfig

__all__ = ["ScenarioRun"]

MARKER = "tanklab_site"
STACK_MARKER = "tanklab_stack"
STACK_OPTIONS = ("clock", "speed", "historian", "role")


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("tanklab")
    group.addoption("--tanklab-config", default=None, help="Site config YAML for the tanklab fixtures.")
    group.addoption(
        "--tanklab-clock",
        default=None,
        choices=("lockstep", "realtime"),
        help="How tanklab_stack runs model time unless a test's marker says (default: lockstep).",
    )
    parser.addini("tanklab_config", "Site config YAML for the tanklab fixtures (relative to the ini file).")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        f"{MARKER}(config=None, overrides=None, supervisor_mode=None): the site the tanklab fixtures use",
    )
    config.addinivalue_line(
        "markers",
        f"{STACK_MARKER}(clock='lockstep', speed=None, historian=False, role='operator'): "
        "how tanklab_stack runs",
    )


def _marker(request: pytest.FixtureRequest) -> Mapping[str, Any]:
    mark = request.node.get_closest_marker(MARKER)
    if mark is None:
        return {}
    unknown = set(mark.kwargs) - {"config", "overrides", "supervisor_mode"}
    if mark.args or unknown:
        pytest.fail(f"@pytest.mark.{MARKER} takes config=, overrides=, supervisor_mode= only", pytrace=False)
    return mark.kwargs


@pytest.fixture
def tanklab_config(request: pytest.FixtureRequest) -> Path:
    """The site config file the tanklab fixtures use (see the module docstring for the order)."""
    config = request.config
    given = _marker(request).get("config") or config.getoption("--tanklab-config")
    if given:
        path = Path(given)
    elif config.getini("tanklab_config"):
        base = Path(config.inipath).parent if config.inipath else Path(config.rootpath)
        path = base / str(config.getini("tanklab_config"))
    elif os.environ.get("TANKLAB_CONFIG"):
        path = Path(os.environ["TANKLAB_CONFIG"])
    else:
        pytest.fail(
            "tanklab: no site config: give @pytest.mark.tanklab_site(config=...), --tanklab-config, "
            "the ini option tanklab_config or TANKLAB_CONFIG",
            pytrace=False,
        )
    if not path.is_file():
        pytest.fail(f"tanklab: site config {path}: no such file", pytrace=False)
    return path


@pytest.fixture
def tanklab_site_overrides(request: pytest.FixtureRequest) -> dict[str, Any]:
    """Dotted-path overrides of the site file (a scenario variant's ``set:``)."""
    return dict(_marker(request).get("overrides") or {})


@pytest.fixture
def tanklab_site(tanklab_config: Path, tanklab_site_overrides: dict[str, Any]) -> SiteConfig:
    """The validated site: the config file with the overrides applied."""
    from tanklab.config import ConfigError, read_yaml, site_from_mapping
    from tanklab.scenario import apply_overrides

    try:
        data = apply_overrides(read_yaml(tanklab_config), tanklab_site_overrides)
        return site_from_mapping(data, tanklab_config)
    except KeyError as e:
        pytest.fail(f"tanklab: {tanklab_config}: override {e.args[0]}", pytrace=False)
    except ConfigError as e:
        pytest.fail(f"tanklab: {e}", pytrace=False)


@pytest.fixture
def tanklab_cosim(request: pytest.FixtureRequest, tanklab_site: SiteConfig) -> CoSimulation:
    """A fresh co-simulation of the site (supervisor mode from the marker, when it has one)."""
    from tankctl.cosim import CoSimulation
    from tanklab_io.threads import limit_blas_threads

    limit_blas_threads()  # one BLAS thread, as in the tiers
    mode = _marker(request).get("supervisor_mode")
    if mode is not None and tanklab_site.supervisor is None:
        pytest.fail(
            f"tanklab: site {tanklab_site.name} has no supervisor for supervisor_mode={mode}", pytrace=False
        )
    return CoSimulation(tanklab_site, supervisor_mode=mode)


@dataclass
class ScenarioRun:
    """A scenario run in the co-simulation: its result and a check of its expectations."""

    result: ScenarioResult

    def assert_expectations(self) -> None:
        """Fail the test, one line per unmet ``expect:`` bound, unless every one is met."""
        from tankctl.simulate.expect import check_expectations

        if not self.result.scenario.expect:
            pytest.fail(
                f"tanklab: scenario {self.result.scenario.name} has no expect: section", pytrace=False
            )
        failed = [o.line() for o in check_expectations(self.result) if not o.passed]
        if failed:
            pytest.fail("\n".join(failed), pytrace=False)


@pytest.fixture
def tanklab_scenario() -> Callable[..., ScenarioRun]:
    """``run(path, variants=None, config=None) -> ScenarioRun``: a scenario in the co-simulation."""
    from tankctl.simulate import run_scenario
    from tanklab.errors import TanklabError
    from tanklab_io.threads import limit_blas_threads

    limit_blas_threads()

    def run(
        path: str | Path, variants: Sequence[str] | None = None, config: str | Path | None = None
    ) -> ScenarioRun:
        try:
            return ScenarioRun(run_scenario(path, config=config, variants=variants))
        except TanklabError as e:
            pytest.fail(f"tanklab: {e}", pytrace=False)

    return run


@pytest.fixture(scope="session")
def tanklab_logins(tmp_path_factory: pytest.TempPathFactory) -> Logins:
    """A throw-away security home for the session's stacks: a PKI and one user per login role."""
    from tankctl.testing.logins import provision_users

    return provision_users(tmp_path_factory.mktemp("tanklab-home"))


def _stack_marker(request: pytest.FixtureRequest) -> dict[str, Any]:
    mark = request.node.get_closest_marker(STACK_MARKER)
    if mark is None:
        return {}
    if mark.args or set(mark.kwargs) - set(STACK_OPTIONS):
        pytest.fail(f"@pytest.mark.{STACK_MARKER} takes {'=, '.join(STACK_OPTIONS)}= only", pytrace=False)
    return dict(mark.kwargs)


@pytest.fixture
def tanklab_stack_factory(
    request: pytest.FixtureRequest,
    tanklab_config: Path,
    tanklab_site_overrides: dict[str, Any],
    tanklab_site: SiteConfig,
    tanklab_logins: Logins,
    tmp_path: Path,
) -> Iterator[Callable[..., RunningStack]]:
    """``start(clock=None, speed=None, historian=None, role=None)``: the site's tiers serving
    until the test ends (see the module docstring)."""
    import contextlib

    import yaml

    from tankctl.testing.fixture import StackError, StackOptions, running_stack
    from tanklab.config import read_yaml
    from tanklab.scenario import apply_overrides
    from tanklab_io.threads import limit_blas_threads

    limit_blas_threads()
    config = tanklab_config
    if tanklab_site_overrides:  # the tiers read a file: the overridden site written for them
        config = tmp_path / f"{tanklab_site.name}.yaml"
        data = apply_overrides(read_yaml(tanklab_config), tanklab_site_overrides)
        config.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    defaults = {"clock": request.config.getoption("--tanklab-clock") or "lockstep", **_stack_marker(request)}
    started = 0

    with contextlib.ExitStack() as stacks:

        def start(
            clock: str | None = None,
            speed: float | None = None,
            historian: bool | None = None,
            role: str | None = None,
        ) -> RunningStack:
            nonlocal started
            given = {"clock": clock, "speed": speed, "historian": historian, "role": role}
            chosen = {**defaults, **{k: v for k, v in given.items() if v is not None}}
            started += 1
            scratch = tmp_path / f"stack-{started}"
            scratch.mkdir()
            try:
                options = StackOptions(**chosen)
            except (StackError, TypeError) as e:
                pytest.fail(str(e), pytrace=False)
            return stacks.enter_context(running_stack(tanklab_site, config, tanklab_logins, scratch, options))

        yield start


@pytest.fixture
def tanklab_stack(tanklab_stack_factory: Callable[..., RunningStack]) -> RunningStack:
    """The site's tiers serving for the test, with the marker's options (see the module docstring)."""
    return tanklab_stack_factory()
