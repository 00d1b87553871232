"""tanklab's pytest plugin (tankctl.pytest_plugin, entry point pytest11 ``tanklab``; issue 18).

- Through pytest's own ``pytester`` (in-process runs): the fixtures resolve the
  config from the marker, the option, the ini file and the environment, in that order; overrides
  apply; a missing or broken config fails the test in one line; ``tanklab_scenario`` passes and
  fails on a scenario's expectations.
- In a fresh virtual environment where only tanklab (and pytest) is installed from this checkout,
  the shipped example test file passes: the plugin is found through its entry point, and its
  ``tanklab_stack`` test runs the plant and PLC processes from the installed wheel.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

# The inner runs are in this process: what their fixtures import lazily is imported here first,
# so that pytester's restore of sys.modules after a run never drops numpy (which cannot load twice).
import tankctl.cosim
import tankctl.simulate.expect  # noqa: F401
from helpers import ROOT

pytest_plugins = ["pytester"]

SITE = ROOT / "configs" / "single_tank_short_sim.yaml"


def test_the_marker_config_and_overrides_reach_the_site_and_the_cosim(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        f"""
        import pytest

        @pytest.mark.tanklab_site(config={str(SITE)!r}, overrides={{"plc.loops.0.setpoint_m": 0.1}})
        def test_site(tanklab_site, tanklab_cosim):
            assert tanklab_site.name == "single_tank_short_sim"
            assert tanklab_site.plc.loops[0].setpoint_m == 0.1
            level = tanklab_cosim.run(30.0).array("levels_m")[:, 0]
            assert abs(level[-1] - 0.1) < 2e-3
        """
    )
    pytester.runpytest("-p", "no:cacheprovider").assert_outcomes(passed=1)


@pytest.mark.parametrize("how", ["option", "ini", "env"])
def test_the_config_comes_from_the_option_the_ini_file_or_the_environment(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch, how: str
) -> None:
    pytester.makepyfile(
        """
        def test_site(tanklab_site):
            assert tanklab_site.name == "single_tank_short_sim"
        """
    )
    args = ["-p", "no:cacheprovider"]
    monkeypatch.delenv("TANKLAB_CONFIG", raising=False)
    if how == "option":
        args += ["--tanklab-config", str(SITE)]
    elif how == "ini":
        (pytester.path / "configs").mkdir()
        (pytester.path / "configs" / "site.yaml").write_text(SITE.read_text())
        pytester.makeini("[pytest]\ntanklab_config = configs/site.yaml\n")
    else:
        monkeypatch.setenv("TANKLAB_CONFIG", str(SITE))
    pytester.runpytest(*args).assert_outcomes(passed=1)


def test_no_config_and_a_broken_one_fail_in_one_line(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    broken = tmp_path / "broken.yaml"
    data = yaml.safe_load(SITE.read_text())
    data["plc"]["scan_period_s"] = -1
    broken.write_text(yaml.safe_dump(data))
    pytester.makepyfile(
        f"""
        import pytest

        def test_none(tanklab_site):
            pass

        @pytest.mark.tanklab_site(config={str(broken)!r})
        def test_broken(tanklab_site):
            pass

        @pytest.mark.tanklab_site(config={str(SITE)!r}, overrides={{"plc.nope.x": 1}})
        def test_bad_override(tanklab_site):
            pass
        """
    )
    monkeypatch.delenv("TANKLAB_CONFIG", raising=False)
    result = pytester.runpytest("-p", "no:cacheprovider", "-rf")
    result.assert_outcomes(errors=3)  # a fixture that fails is an error of the test's set-up
    out = result.stdout.str()
    assert "tanklab: no site config: give @pytest.mark.tanklab_site(config=...)" in out
    assert f"tanklab: {broken}: plc.scan_period_s:" in out
    assert "override plc.nope: no such field" in out


def test_tanklab_scenario_passes_and_fails_on_expectations(pytester: pytest.Pytester, tmp_path: Path) -> None:
    def scenario(name: str, iae_max: float) -> Path:
        path = tmp_path / f"{name}.yaml"
        body = {
            "name": name,
            "site": str(SITE),
            "duration_s": 5.0,
            "initial": {"levels_m": [0.05], "setpoints_m": {"LIC1": 0.05}},
            "events": [{"at_s": 1.0, "kind": "setpoint", "loop": "LIC1", "value_m": 0.07}],
            "expect": [{"loop": "LIC1", "metric": "iae", "max": iae_max}],
        }
        path.write_text(yaml.safe_dump(body))
        return path

    loose, tight = scenario("loose", 10.0), scenario("tight", 0.0)
    pytester.makepyfile(
        f"""
        def test_loose(tanklab_scenario):
            tanklab_scenario({str(loose)!r}).assert_expectations()

        def test_tight(tanklab_scenario):
            run = tanklab_scenario({str(tight)!r})
            assert run.result.variants["default"].loops["LIC1"].iae > 0
            run.assert_expectations()
        """
    )
    result = pytester.runpytest("-p", "no:cacheprovider", "-rf")
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["*FAIL  default LIC1 iae: * is above 0, expected <= 0*"])


def test_the_example_passes_in_a_fresh_venv_with_only_tanklab_installed(tmp_path: Path) -> None:
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    install = subprocess.run(
        [str(py), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", str(ROOT), "pytest"],
        capture_output=True,
        text=True,
        timeout=1200,
        check=False,
    )
    assert install.returncode == 0, install.stderr[-3000:]
    work = tmp_path / "user"
    work.mkdir()
    (work / "test_my_controller.py").write_text((ROOT / "examples/pytest/test_my_controller.py").read_text())
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "TANKLAB_CONFIG")}
    run = subprocess.run(
        [str(py), "-m", "pytest", "-q", "-p", "no:cacheprovider", "--tanklab-config", str(SITE)],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert "3 passed" in run.stdout  # two co-simulation tests and one on the real processes
    # the installed tanklab, not this checkout: the venv's site-packages hold the plugin
    where = subprocess.run(
        [str(py), "-c", "import tankctl.pytest_plugin as p; print(p.__file__)"],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    assert str(venv) in where.stdout
