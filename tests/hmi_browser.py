"""The HMI's browser tests' support: a real stack with the real HMI server, and headless Chromium.

:class:`HmiStack` is ``tankctl up`` (plant, PLC, supervisor, historian) on a free port block
plus ``tankctl hmi`` on a free port, both run by :class:`~tanklab_testing.procs.TankctlProcess`
on an event loop of their own in a background thread (:class:`LoopThread`): Selenium's calls
block, and the processes' output must be read meanwhile. ``HmiStack.stop`` stops both (and
kills, by id, whatever of them is left) on every path.

:class:`Browser` is Debian's ``/usr/bin/chromium`` driven through ``/usr/bin/chromedriver``
(headless, ``--no-sandbox`` because the tests run as root; Selenium downloads nothing when the
driver's path is given), with a download directory of its own (the trend's CSV and PNG exports
land there) and the page's console log kept, so a test can assert that the front end raised no
error. Every wait is bounded (Selenium's ``WebDriverWait``).

Screenshots go to ``docs/img/hmi-*.png`` when ``TANKLAB_SCREENSHOTS=1`` (docs/hmi.md, Screens).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from collections.abc import Callable, Coroutine, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from selenium import webdriver
from selenium.common.exceptions import StaleElementReferenceException, WebDriverException
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.remote.webelement import WebElement
from selenium.webdriver.support.ui import Select, WebDriverWait

from helpers import ROOT
from tanklab_testing.browser import CHROMEDRIVER, CHROMIUM, chrome_options
from tanklab_testing.procs import TankctlProcess, UpProcess, free_base_port, free_port
from tanklab_testing.waits import wait_until

SCREENSHOTS = os.environ.get("TANKLAB_SCREENSHOTS") == "1"
IMG = ROOT / "docs" / "img"
T = TypeVar("T")


class LoopThread:
    """An asyncio event loop in a daemon thread: the processes' coroutines run there."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name="hmi-stack-loop", daemon=True)
        self.thread.start()

    def run(self, coro: Coroutine[Any, Any, T], timeout_s: float = 300.0) -> T:
        """Run ``coro`` on the loop and wait (bounded) for its result."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout_s)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        if not self.loop.is_running():
            self.loop.close()


def http_json(url: str, timeout_s: float = 5.0) -> tuple[int, Any]:
    """GET ``url``: (status, parsed JSON body or None); status 0 when nothing answers."""
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as resp:  # loopback only
            return resp.status, json.loads(resp.read() or b"null")
    except urllib.error.HTTPError as e:
        return e.code, None
    except (OSError, ValueError):
        return 0, None


@dataclass
class HmiStack:
    """A running stack (``tankctl up``) and its HMI (``tankctl hmi``)."""

    loop: LoopThread
    up: UpProcess
    hmi: TankctlProcess
    base: int
    port: int

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @classmethod
    def start(cls, log_dir: Path, config: Path, *up_args: str) -> HmiStack:
        """``tankctl up --config CONFIG UP_ARGS`` and ``tankctl hmi`` against it; returns when
        the HMI's /healthz says every tier is reachable."""
        loop = LoopThread()
        base, port = free_base_port(), free_port()
        up = UpProcess(base, log_dir / "var", "--no-board", *up_args, config=config)
        hmi = TankctlProcess(
            "hmi",
            "--config",
            str(config),
            "--base-port",
            str(base),
            "--port",
            str(port),
            name="hmi",
            ready=None,
            log=log_dir / "hmi.log",
            ports=[port],
        )
        stack = cls(loop, up, hmi, base, port)
        try:
            loop.run(up.start())
            loop.run(hmi.start())
            loop.run(stack._healthy())
        except BaseException:
            stack.stop()
            raise
        return stack

    async def _healthy(self) -> None:
        async def serving() -> bool:
            if not self.hmi.running:
                raise RuntimeError(f"tankctl hmi exited: {self.hmi.log_text()[-2000:]}")
            if not self.up.running:
                raise RuntimeError(f"tankctl up exited: {self.up.lines[-30:]}")
            status, body = await asyncio.to_thread(http_json, f"{self.url}/healthz")
            return status == 200 and bool(body) and all(body.get("tiers", {}).values())

        await wait_until(serving, 120, what="the HMI's /healthz: every tier reachable", poll_s=0.5)

    def stop(self) -> None:
        """Stop the HMI and the stack; kill (by id) whatever of them is left."""
        try:
            for proc in (self.hmi, self.up):
                if proc.proc is None:
                    continue
                with contextlib.suppress(Exception):
                    self.loop.run(proc.stop(), 120)
                self.loop.run(proc.cleanup(), 60)
        finally:
            self.loop.close()

    def tankctl(self, *args: str) -> subprocess.CompletedProcess[str]:
        """An operator command against the stack (``--base-port``), bounded."""
        return subprocess.run(
            [sys.executable, "-m", "tankctl", *args, "--base-port", str(self.base)],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=120,
            check=False,
        )


class Browser:
    """One headless Chromium session (its own profile and download directory)."""

    def __init__(self, downloads: Path, width: int = 1400, height: int = 1100) -> None:
        assert CHROMIUM.exists() and CHROMEDRIVER.exists(), (
            f"{CHROMIUM} and {CHROMEDRIVER} are needed: `make tools` installs chromium and chromium-driver"
        )
        self.downloads = downloads
        downloads.mkdir(parents=True, exist_ok=True)
        opts = chrome_options(width, height)
        opts.add_experimental_option(
            "prefs",
            {"download.default_directory": str(downloads), "download.prompt_for_download": False},
        )
        opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
        self.driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=opts)
        self.console: list[dict[str, Any]] = []

    def close(self) -> None:
        with contextlib.suppress(WebDriverException):
            self.driver.quit()

    # ---- waiting and finding ---------------------------------------------------------------

    def wait(self, condition: Callable[[], T], timeout_s: float = 30.0, what: str = "condition") -> T:
        """Until ``condition()`` is truthy (its value), at most ``timeout_s``; a stale element
        (the page re-rendered it) counts as not yet."""

        def probe(_: Any) -> T:
            try:
                return condition()
            except StaleElementReferenceException:
                return None  # type: ignore[return-value]

        return WebDriverWait(self.driver, timeout_s, poll_frequency=0.2).until(
            probe, f"waited {timeout_s} s for {what}"
        )

    def css(self, selector: str) -> WebElement:
        return self.driver.find_element(By.CSS_SELECTOR, selector)

    def all(self, selector: str) -> list[WebElement]:
        return self.driver.find_elements(By.CSS_SELECTOR, selector)

    def visible(self, selector: str, timeout_s: float = 30.0) -> WebElement:
        def shown() -> WebElement | None:
            found = self.all(selector)
            return found[0] if found and found[0].is_displayed() else None

        return self.wait(shown, timeout_s, f"{selector} shown")

    def js(self, script: str, *args: Any) -> Any:
        return self.driver.execute_script(script, *args)

    def fetch(self, method: str, url: str, body: Any = None, csrf: bool = True) -> dict[str, Any]:
        """A request made by the page itself (its cookie; the session's CSRF token unless
        ``csrf`` is False): {status, body}. The forged requests of the tests."""
        return self.driver.execute_async_script(
            """
            const [method, url, body, csrf, done] = arguments;
            (async () => {
              const s = await (await fetch('/api/session')).json();
              const headers = {'Content-Type': 'application/json'};
              if (csrf) headers['X-CSRF-Token'] = s.csrf;
              const init = {method, headers};
              if (body !== null) init.body = JSON.stringify(body);
              const r = await fetch(url, init);
              let parsed = null;
              try { parsed = await r.json(); } catch (e) { parsed = null; }
              done({status: r.status, body: parsed});
            })().catch((e) => done({status: -1, body: String(e)}));
            """,
            method,
            url,
            body,
            csrf,
        )

    # ---- the HMI's screens ----------------------------------------------------------------

    def open(self, url: str) -> None:
        self.driver.set_script_timeout(30)
        self.driver.get(url)
        self.wait(
            lambda: self.js("return document.body.dataset.state") in ("login", "ready"), 30, "the page loaded"
        )

    def login(self, user: str, password: str) -> None:
        """Log in through the form and wait for the screen (mimic drawn, first values in)."""
        self.visible("#login-form")
        self.css("#login-user").clear()
        self.css("#login-user").send_keys(user)
        self.css("#login-password").send_keys(password)
        self.css("#login-submit").click()
        self.wait(lambda: self.js("return document.body.dataset.state") == "ready", 60, f"{user} logged in")
        self.wait(lambda: self.all("#mimic svg text.value"), 60, "the first live values on the mimic")

    def logout(self) -> None:
        self.css("#logout").click()
        self.visible("#login-form")

    def faceplate(self, key: str, element: str) -> WebElement:
        """Click mimic element ``#element`` and wait for faceplate ``key`` ("loop:LIC1")."""
        # a pointer click at the element's centre, as a user's: whatever is drawn on top there
        # (a tank's water over its vessel) opens the same faceplate
        ActionChains(self.driver).move_to_element(self.css(f"#mimic [id='{element}']")).click().perform()
        return self.wait(
            lambda: (
                self.css("#faceplate")
                if self.css("#faceplate").get_attribute("data-faceplate") == key
                else None
            ),
            10,
            f"faceplate {key}",
        )

    def field(self, name: str) -> WebElement:
        return self.css(f"#faceplate [data-field={name}]")

    def action(self, name: str) -> WebElement:
        return self.css(f"#faceplate [data-action={name}]")

    def enter(self, field: str, action: str, value: str) -> str:
        """Type ``value`` into a faceplate entry, apply it, wait for and return the status line."""
        self.js("arguments[0].textContent = ''", self.field("status"))
        box = self.field(field)
        box.clear()
        box.send_keys(value)
        self.action(action).click()
        return str(
            self.wait(lambda: self.field("status").text or None, 30, f"the status of {action} {value}")
        )

    def choose(self, field: str, action: str, option: str) -> str:
        self.js("arguments[0].textContent = ''", self.field("status"))
        Select(self.field(field)).select_by_value(option)
        self.action(action).click()
        return str(
            self.wait(lambda: self.field("status").text or None, 30, f"the status of {action} {option}")
        )

    def output(self, path: str) -> str:
        """The text of the faceplate's read-only value of ``path``."""
        return str(self.css(f"#faceplate output[data-path='{path}']").text)

    def bar_value(self, label: str) -> float | None:
        text = self.css(f"#faceplate [data-bar={label}] .bar-value").text.split()
        try:
            return float(text[0])
        except (IndexError, ValueError):
            return None

    def errors(self) -> list[str]:
        """The page's script errors so far (SEVERE console entries), kept across calls. An HTTP
        error status is logged as "Failed to load resource": an answer the tests provoke (401,
        403) and the front end shows, not an error of the page's code."""
        self.console += self.driver.get_log("browser")
        return [
            e["message"]
            for e in self.console
            if e.get("level") == "SEVERE" and "Failed to load resource" not in e["message"]
        ]

    def screenshot(self, name: str) -> None:
        """``docs/img/hmi-NAME.png`` when TANKLAB_SCREENSHOTS=1."""
        if SCREENSHOTS:
            IMG.mkdir(parents=True, exist_ok=True)
            self.driver.save_screenshot(str(IMG / f"hmi-{name}.png"))

    def downloaded(self, suffix: str, timeout_s: float = 20.0) -> Path:
        """The newest completed download ending in ``suffix``."""

        def done() -> Path | None:
            files = sorted(self.downloads.glob(f"*{suffix}"), key=lambda p: p.stat().st_mtime)
            return files[-1] if files else None

        return self.wait(done, timeout_s, f"a downloaded *{suffix}")


@contextlib.contextmanager
def browser(downloads: Path) -> Iterator[Browser]:
    """A :class:`Browser`, quit on every path."""
    b = Browser(downloads)
    try:
        yield b
    finally:
        b.close()
