"""The HMI in real headless Chromium against a real stack (issue 17, "What it must show").

One three-tank stack (``tankctl up`` at speed 5, the Energies site started at its operating
point, with T1's low switch raised to 0.2 m) and the real HMI server (``tankctl hmi``) serve the
whole module; each test logs in through the login form like a user. The oracles are the tiers'
own answers: the status codes they return, the values they publish back to the screen, and
``tankctl alarms``, an independent client of the PLC.

- a wrong password is refused on the login form;
- an Operator changes LIC1's SP on the faceplate (an out-of-range entry is refused before it is
  sent), sees the level trend move toward it, exports the shown trend as CSV and PNG, and after
  a reload the trend is drawn again from the historian's record;
- an Operator stops P1 (LIC1 MANUAL, 0 %) and opens a leak on T1: T1Level goes active on the
  banner and in the list, is acknowledged with a comment on the screen, and ``tankctl alarms``
  shows it acknowledged;
- an Observer finds every control disabled, and a forged write (the page's own session and CSRF
  token) is refused by the tier with BadUserAccessDenied, a request without the token with 403;
- the keyboard opens a faceplate (a focused mimic element and Enter);
- an Engineer may reset LIC1's gains (an Operator may not: the button is disabled) and sees the
  supervisor's faceplate with the MPC's plan drawn.
The one- and two-tank sites' mimics are in test_browser_sites.py, a tier's restart in
test_browser_restart.py.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.keys import Keys

from helpers import TEST_PASSWORDS
from hmi_browser import Browser, HmiStack, browser
from tanklab_testing.sites import site_config

pytestmark = pytest.mark.process

LOW_SWITCH_M = 0.2
"""T1's low switch in this module's site: a stopped pump and an open leak cross it within about a
minute of model time (the shipped 0.031 m would not be reached: T3 refills T1)."""


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[HmiStack]:
    root = tmp_path_factory.mktemp("hmi-browser")
    config = site_config(root / "site.yaml", at_operating_point=True, pumps_hold_on_watchdog=True)
    data = yaml.safe_load(config.read_text(encoding="utf-8"))
    data["plant"]["tanks"][0]["switches"] = {"high_m": 0.558, "low_m": LOW_SWITCH_M}
    config.write_text(yaml.safe_dump(data), encoding="utf-8")
    s = HmiStack.start(root, config, "--speed", "5", "--fresh")
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture
def page(stack: HmiStack, tmp_path: Path) -> Iterator[Browser]:
    with browser(tmp_path / "downloads") as b:
        b.open(stack.url)
        yield b
        assert b.errors() == [], "the front end logged errors"


def login(page: Browser, who: str) -> None:
    page.login(who, TEST_PASSWORDS[who])


def test_a_wrong_password_is_refused(page: Browser) -> None:
    page.visible("#login-form")
    page.css("#login-user").send_keys("operator")
    page.css("#login-password").send_keys("not-the-password")
    page.css("#login-submit").click()
    text = page.wait(lambda: page.css("#login-error").text, 30, "the login error")
    assert "refused" in text and "operator" in text, text
    assert not page.css("#main-view").is_displayed()
    assert page.js("return document.body.dataset.state") == "login"


def test_operator_changes_the_setpoint_and_the_level_trend_follows(page: Browser, stack: HmiStack) -> None:
    login(page, "operator")
    assert page.css("#whoami").text == "operator (Operator)"
    page.faceplate("loop:LIC1", "LIC1-bubble")
    assert page.action("reset-gains").get_attribute("disabled") is not None  # Engineer only
    sp_before = page.bar_value("SP")
    assert sp_before == pytest.approx(0.4, abs=1e-6)

    # out of range: refused on the screen, nothing sent, the SP unchanged
    status = page.enter("sp-input", "sp-apply", "0.9")
    assert status.startswith("not sent") and "[0, 0.6]" in status, status
    status = page.enter("sp-input", "sp-apply", "0.45")
    assert status == "Good", status
    page.wait(lambda: page.bar_value("SP") == pytest.approx(0.45), 30, "the PLC to publish SP 0.45")
    page.screenshot("faceplate")

    # the level moves toward the new setpoint: seen on the faceplate, then in the exported trend
    page.wait(lambda: (page.bar_value("PV") or 0) > 0.42, 120, "PV rising toward 0.45 m")
    page.screenshot("overview")
    # the page's own latency samples (source timestamp to DOM update, one clock: this machine's)
    latency = page.js("return window.tanklabHmi.parts.latency")
    assert latency and min(latency) > -0.05, latency[:10]
    page.css("#trend-pane [data-action=export-csv]").click()
    rows = list(csv.DictReader(io.StringIO(page.downloaded(".csv").read_text(encoding="utf-8"))))
    assert rows and set(rows[0]) >= {"time_epoch_s", "PLC.LIC1.PV", "PLC.LIC1.SP"}
    pv = [float(r["PLC.LIC1.PV"]) for r in rows if r["PLC.LIC1.PV"]]
    sp = [float(r["PLC.LIC1.SP"]) for r in rows if r["PLC.LIC1.SP"]]
    assert sp[0] == pytest.approx(0.4) and sp[-1] == pytest.approx(0.45), (
        "SP overlaid: the step is in the trend"
    )
    assert min(pv) < 0.41 and pv[-1] > 0.42, "PV drawn moving from the old setpoint toward the new one"
    times = [float(r["time_epoch_s"]) for r in rows]
    assert times == sorted(times)
    page.css("#trend-pane [data-action=export-png]").click()
    png = page.downloaded(".png").read_bytes()
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) > 2000

    # after a reload the trend comes back from the historian's record (not only live values)
    loaded_at = page.js("return Date.now() / 1000")
    page.driver.refresh()
    page.wait(
        lambda: page.js("return document.body.dataset.state") == "ready", 60, "the screen after a reload"
    )

    def history_drawn() -> bool:
        return int(page.css("#trend-pane").get_attribute("data-points") or 0) > 10

    page.wait(history_drawn, 60, "the trend drawn from the historian after the reload")
    for old in page.downloads.glob("*.csv"):
        old.unlink()
    page.css("#trend-pane [data-action=export-csv]").click()
    rows = list(csv.DictReader(io.StringIO(page.downloaded(".csv").read_text(encoding="utf-8"))))
    older = [r for r in rows if float(r["time_epoch_s"]) < loaded_at - 5 and r["PLC.LIC1.PV"]]
    assert older, "rows recorded before the reload come from /api/trend (the historian)"
    page.logout()


def test_operator_acknowledges_the_leak_alarm_with_a_comment(page: Browser, stack: HmiStack) -> None:
    login(page, "operator")
    # stop the pump by hand: LIC1 MANUAL at 0 % (so the leak drains T1 instead of being rejected)
    page.faceplate("loop:LIC1", "LIC1-bubble")
    assert page.choose("mode", "mode-apply", "MANUAL") == "Good"
    assert page.enter("manual-input", "manual-apply", "0") == "Good"
    page.faceplate("tank:T1", "T1-vessel")
    assert page.enter("leak-input", "leak-apply", "1.5").startswith("not sent")
    # the disturbance's range is the plant's: the tier refuses, the faceplate shows its status code
    assert page.enter("disturbance-input", "disturbance-apply", "1").startswith("BadOutOfRange")
    assert page.enter("leak-input", "leak-apply", "1") == "Good"
    row = "#alarm-list tr[data-alarm-id='plc:T1Level']"

    def active() -> bool:
        found = page.all(row)
        return bool(found) and found[0].get_attribute("data-active") == "true"

    def banner_is_the_top_unacked_row() -> None:
        # the list is in rank order (priority, severity, time): the banner shows its first
        # unacknowledged row (on a loaded machine another alarm, e.g. a PV bad, may outrank T1Level)
        rows = [
            tr for tr in page.all("#alarm-list tr[data-alarm-id]") if tr.get_attribute("data-acked") != "true"
        ]
        banner = page.css("#alarm-banner")
        assert rows, "no unacknowledged row"
        assert banner.get_attribute("data-alarm-id") == rows[0].get_attribute("data-alarm-id"), banner.text
        assert rows[0].get_attribute("data-alarm-id").split(":")[1] in banner.text

    page.wait(active, 120, "T1Level active in the alarm list")
    assert page.css(row).get_attribute("data-acked") != "true"
    banner_is_the_top_unacked_row()
    assert page.css(f"{row} [data-field=state]").text.startswith("ACTIVE UNACKED")
    page.wait(
        lambda: "abnormal" in (page.css("#mimic [id='T1-leak']").get_attribute("class") or ""),
        10,
        "leak mark",
    )
    page.screenshot("alarm")
    page.css(f"{row} [data-field=comment]").send_keys("leak opened by the browser test")
    page.css(f"{row} [data-action=ack]").click()
    page.wait(
        lambda: page.css(row).get_attribute("data-acked") == "true", 30, "T1Level acknowledged on the screen"
    )
    assert "ack plc:T1Level: Good" in page.css("#alarm-status").text
    assert page.css("#alarm-banner").get_attribute("data-alarm-id") != "plc:T1Level"

    # an independent client, the CLI, sees it acknowledged
    r = stack.tankctl("alarms", "--json")
    assert r.returncode == 0, r.stderr
    t1 = next(a for a in json.loads(r.stdout) if a["tier"] == "plc" and a["name"] == "T1Level")
    assert t1["acked"] is True and t1["active"] is True, t1

    # the alarm history (from the historian) has the activation
    page.css("#alarms-pane [data-action=alarm-history]").click()
    page.wait(lambda: page.all("#alarm-history tbody tr"), 60, "the alarm history")
    assert any("T1Level" in tr.text for tr in page.all("#alarm-history tbody tr"))

    # the row's source opens its faceplate (the tank's, for the level alarm)
    page.faceplate("loop:LIC1", "LIC1-bubble")
    page.css(f"{row} [data-action=goto]").click()
    page.wait(
        lambda: page.css("#faceplate").get_attribute("data-faceplate") == "tank:T1", 10, "T1 from the row"
    )

    # back to normal operation for the next tests
    assert page.enter("leak-input", "leak-apply", "0") == "Good"
    page.faceplate("loop:LIC1", "LIC1-bubble")
    assert page.choose("mode", "mode-apply", "AUTO") == "Good"
    page.logout()


def test_observer_sees_every_control_disabled_and_a_forged_write_is_refused(page: Browser) -> None:
    login(page, "observer")
    assert page.css("#whoami").text == "observer (Observer)"
    for key, element in (("loop:LIC1", "LIC1-bubble"), ("tank:T1", "T1-vessel"), ("valve:V13", "V13-valve")):
        page.faceplate(key, element)
        controls = page.all("#faceplate [data-write]")
        assert controls, key
        assert all(not c.is_enabled() for c in controls), [c.get_attribute("data-action") for c in controls]
    page.faceplate("loop:LIC1", "LIC1-bubble")
    page.screenshot("observer")
    for button in page.all("#alarm-list button, #alarm-list input, #alarm-list select"):
        if button.get_attribute("data-action") != "goto":
            assert not button.is_enabled()
    sp = page.bar_value("SP")

    forged = page.fetch("POST", "/api/write", {"path": "PLC.LIC1.SP", "value": 0.3})
    assert forged["status"] == 200 and forged["body"]["ok"] is False, forged
    assert forged["body"]["status"] == "BadUserAccessDenied", forged
    no_token = page.fetch("POST", "/api/write", {"path": "PLC.LIC1.SP", "value": 0.3}, csrf=False)
    assert no_token["status"] == 403, no_token
    leak = page.fetch("POST", "/api/write", {"path": "Plant.T1.Leak", "value": 0.5})
    assert leak["body"]["status"] == "BadUserAccessDenied", leak
    assert page.bar_value("SP") == sp
    page.logout()


def test_engineer_resets_gains_and_sees_the_mpc_plan(page: Browser) -> None:
    login(page, "engineer")
    # the keyboard reaches the mimic: a focused element opens its faceplate with Enter
    page.js("document.getElementById('T2-vessel').focus()")
    ActionChains(page.driver).send_keys(Keys.ENTER).perform()
    page.wait(
        lambda: page.css("#faceplate").get_attribute("data-faceplate") == "tank:T2", 10, "tank:T2 by Enter"
    )
    page.faceplate("loop:LIC1", "LIC1-bubble")
    reset = page.action("reset-gains")
    assert reset.is_enabled()
    page.js("arguments[0].textContent = ''", page.field("status"))
    reset.click()
    assert page.wait(lambda: page.field("status").text, 30, "reset-gains status") == "Good"

    # the trend zooms and pans (and stops following the present), "Live" follows it again
    def span() -> float:
        return float(page.js("const x = window.tanklabHmi.parts.trend.chart.scales.x; return x.max - x.min"))

    live = page.css("#trend-pane [data-action=trend-live]")
    assert span() == pytest.approx(300, abs=2)  # the default 5 min
    page.css("#trend-pane [data-action=trend-zoom-in]").click()  # redrawn once history is in
    page.wait(lambda: span() == pytest.approx(150, abs=2), 10, "half the range shown")
    assert live.get_attribute("aria-pressed") == "false"
    left = float(page.js("return window.tanklabHmi.parts.trend.chart.scales.x.min"))
    page.css("#trend-pane [data-action=trend-pan-left]").click()
    page.wait(
        lambda: (
            page.js("return window.tanklabHmi.parts.trend.chart.scales.x.min")
            == pytest.approx(left - 75, abs=2)
        ),
        10,
        "the range moved back by half its width",
    )
    assert span() == pytest.approx(150, abs=2)
    live.click()
    page.wait(lambda: span() == pytest.approx(300, abs=2), 10, "the live 5 min again")
    assert live.get_attribute("aria-pressed") == "true"
    over = page.css("#trend .u-over")  # a dragged quarter of the plot zooms to it
    width = over.size["width"]
    ActionChains(page.driver).move_to_element_with_offset(
        over, -width // 4, 0
    ).click_and_hold().move_by_offset(width // 4, 0).release().perform()
    page.wait(lambda: span() == pytest.approx(75, rel=0.1), 10, "the dragged range shown")
    assert live.get_attribute("aria-pressed") == "false"
    live.click()

    page.css("#open-supervisor").click()
    page.wait(
        lambda: page.css("#faceplate").get_attribute("data-faceplate") == "supervisor", 10, "supervisor"
    )
    assert page.choose("supervisor-mode", "supervisor-mode-apply", "MPC") == "Good"
    page.wait(lambda: page.all("#mpc-plan canvas"), 60, "the MPC's predicted PV and planned MV drawn")
    page.screenshot("supervisor")
    assert page.choose("supervisor-mode", "supervisor-mode-apply", "ADVISORY") == "Good"
    page.logout()
