"""Robustness of the secured PLC server: protocol fuzz, write flood, freeze-then-crash, parked sockets.

Issue #7, item 7. Every measurement runs real tier processes (``python -m tankctl plant | plc |
supervisor``, a :class:`tanklab_testing.stack.Stack`) on free loopback ports, secured with a
security home made for the run in a temporary directory (a PKI and one engineer login,
``--home``). The case generators, oracles and post-conditions are the test-support package's
(:mod:`tanklab_testing.security`), which the CI-sized tests in ``tests/robustness/`` drive with
small sizes; the functions here are the full-size runs of ``make bench``.

:func:`fuzz` (``n_cases``, ``seed``)
    A seeded protocol fuzz of the PLC server while it scans against a real plant. Raw-transport
    cases, each on a fresh socket (``RAW_KINDS``): random bytes; Hello messages with absurd
    buffer sizes, URL lengths and length prefixes that lie; MSG / OPN / CLO with bogus channel
    ids; chunk headers announcing more than 64 KiB or less than 8 bytes; unknown message types;
    truncated frames; valid Hello + OpenSecureChannel bytes with flipped bytes; OPN with
    garbage certificates or unknown policies; and, on an opened unencrypted (discovery) channel,
    more than 4 chunks per message, more than 16 queued messages, and requests with flipped
    bytes. Typed cases through authenticated sessions (the engineer's login and the supervisor's
    tier identity, ``SESSION_KINDS``): writes of random Variant types (scalars, arrays,
    matrices, NaN, infinities, out-of-EURange values, non-members of enumerations, non-Good
    status codes, client timestamps, index ranges, attributes other than Value) to every PLC
    node, its EURange / EnumStrings / EngineeringUnits properties, standard nodes and unknown
    nodes; method calls with random arguments (counts, types, NaN, outside the gain box, on the
    wrong object); node-management requests (AddNodes, DeleteNodes, AddReferences,
    DeleteReferences); subscriptions with absurd parameters.

    Oracles: a write or call the contract must refuse (``write_must_refuse``,
    ``call_must_refuse``, written independently of ``tanklab_io.ua``'s checks) that answers
    Good is a violation, and so is a node-management request that succeeds or a raw case of a
    kind the transport limits must close (``MUST_CLOSE``) that the server leaves open.
    Post-conditions (``post_conditions``): the server still serves a new secure session;
    a Read is Good; no stored value of any PLC node lies outside its EURange, is not finite, is
    of the wrong type or outside its enumeration, and the EURange properties are unchanged; the
    scan counter still advances.

:func:`flood` (``seconds``, ``clients``)
    ``clients`` engineer sessions write as fast as they can (one request in flight each) a mix of
    valid and invalid values to SP, ManualMV and Mode (valid writes keep the loops regulating:
    SP within 2 cm of 0.4 m / 0.2 m, Mode AUTO) while the PLC scans at speed 5 (200 ms of wall
    time per scan). Reported: writes per second accepted and refused (by status), overruns
    before and after, the largest ``LastScanDuration`` seen, the PLC's model time against the
    plant's over the flood (a PLC that skips deadlines falls behind), scan lateness from the
    PLC's stop line.

:func:`freeze_crash` (``repeats``)
    Plant, PLC and supervisor at speed 5. Each repeat: SIGSTOP the PLC for 3 s, SIGCONT, wait for
    recovery, SIGKILL it and restart it on the same port with the same retentive-memory file,
    wait for recovery. The supervisor is sampled every 50 ms: a *silent stall* is a PLC absence
    (freeze or crash) during which ``Supervisor.PlcConnected`` never went False, or a recovery
    that does not come within 60 s (``PlcConnected`` True, ``Supervisor.Cycle`` advancing past
    its value before the fault and ``PLC.Supervisor.Alive`` True). Recovery times in wall
    seconds: from SIGCONT, and from the restarted PLC's banner.

:func:`idle_sockets` (``n``)
    ``n`` raw TCP sockets parked on the PLC's port without a Hello; then a legitimate secure
    client connects and reads (target <= 1 s, reported), and every parked socket should be
    closed by the server after the 2 s handshake limit (time to closure reported).

:func:`login_storm` (``n``, ``concurrency``)
    Failed password logins with unknown user names, ``concurrency`` at a time, against the PLC
    at speed 5; the scan overruns they cause are reported (there were 2 to 4 while the scrypt
    check ran inside the server's event loop; it now runs in a worker thread).

Every stack starts at the default config's operating point (``site_config``): the loops
regulate from the first scan instead of filling empty tanks. :func:`run_all` and
:func:`markdown` give ``benchmarks/run.py`` the results and a section of ``docs/benchmarks.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import signal
import tempfile
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

from benchmarks.common import Summary, fmt
from benchmarks.stack import LATENESS_RE
from tanklab_io.ua_client import new_client
from tanklab_io.ua_security import LIMITS, ClientIdentity, secure_client
from tanklab_io.users import Credentials
from tanklab_testing.logins import Logins, Probe, provision, quiet_disconnect, session
from tanklab_testing.procs import free_base_port
from tanklab_testing.security import (
    MUST_CLOSE,
    RAW_KINDS,
    SESSION_KINDS,
    fuzz_server,
    post_conditions,
    read_scan,
    status_after_scans,
    watched_flood,
)
from tanklab_testing.sites import HOST, SITE, site_config
from tanklab_testing.stack import Stack

FUZZ_SPEED = 10.0
FLOOD_SPEED = 5.0
FAIL_SPEED = 5.0
RECOVERY_LIMIT_S = 60.0


@contextlib.asynccontextmanager
async def stack(
    speed: float, *, supervisor: bool = False, retain: bool = False
) -> AsyncIterator[tuple[Stack, Logins]]:
    """A temporary security home and config, and plant + PLC (+ supervisor) at ``speed``, with
    their logs in the temporary directory (kept in ``Stack.logs`` when they stop)."""
    with tempfile.TemporaryDirectory(prefix="tanklab-security-") as tmp:
        root = Path(tmp)
        logins = provision(root / "home")
        config = site_config(
            root / "site.yaml", retain=root / "plc-retain.json" if retain else None, at_operating_point=True
        )
        st = Stack(
            config,
            free_base_port(3),
            speed=speed,
            state_file=root / "plant-state.json",
            home=logins.home.root,
            log_dir=root,
            logins=logins,
        )
        try:
            await st.up(("plant", "plc", "supervisor") if supervisor else ("plant", "plc"))
            yield st, logins
        finally:
            await st.down()


async def fuzz_async(n_cases: int = 5000, seed: int = 0) -> dict[str, Any]:
    async with stack(FUZZ_SPEED) as (st, logins):
        started = time.perf_counter()
        counts = await fuzz_server(st.plc_url, logins, n_cases=n_cases, seed=seed)
        wall = time.perf_counter() - started
        post = await post_conditions(st.plc_url, logins)
    return {
        "n_cases": n_cases,
        "seed": seed,
        "speed": FUZZ_SPEED,
        "wall_s": wall,
        **counts.as_dict(),
        "post": {
            "alive": post.alive,
            "read_good": post.read_good,
            "out_of_contract": post.out_of_contract,
            "scan_before": post.scan_before,
            "scan_after": post.scan_after,
            "error": post.error,
            "ok": post.ok,
        },
    }


def fuzz(n_cases: int = 5000, seed: int = 0) -> dict[str, Any]:
    """The protocol fuzz of the PLC server (see the module docstring)."""
    return asyncio.run(fuzz_async(n_cases, seed))


async def flood_async(seconds: float = 60.0, clients: int = 4) -> dict[str, Any]:
    async with stack(FLOOD_SPEED) as (st, logins):
        counts, watch = await watched_flood(
            st.plc_url, st.plant_url, logins, seconds=seconds, clients=clients
        )
    lateness = LATENESS_RE.findall(st.logs.get("plc-0.log", ""))
    p50, p99 = (float(lateness[-1][2]), float(lateness[-1][3])) if lateness else (math.nan, math.nan)
    refused = counts.sent - counts.accepted
    ts = SITE.plc.scan_period_s if SITE.plc else 1.0
    scans = int(watch.after["Scan"]) - int(watch.before["Scan"])
    return {
        "seconds": seconds,
        "clients": clients,
        "speed": FLOOD_SPEED,
        "writes": counts.sent,
        "accepted": counts.accepted,
        "refused": refused,
        "writes_per_s": counts.sent / seconds,
        "accepted_per_s": counts.accepted / seconds,
        "refused_per_s": refused / seconds,
        "statuses": dict(counts.statuses.most_common()),
        "violations": counts.violations,
        "errors": counts.errors,
        "overruns_before": int(watch.before["Overruns"]),
        "overruns_after": int(watch.after["Overruns"]),
        "scans": scans,
        "scans_expected": seconds * FLOOD_SPEED / ts,
        "model_lag_s": watch.model_lag_s,
        "max_scan_duration_ms": 1e3 * watch.max_scan_duration_s,
        "lateness_p50_ms": p50,
        "lateness_p99_ms": p99,
    }


def flood(seconds: float = 60.0, clients: int = 4) -> dict[str, Any]:
    """The write flood (see the module docstring)."""
    return asyncio.run(flood_async(seconds, clients))


async def _until(cond: Callable[[], Awaitable[bool]], limit_s: float, poll_s: float = 0.05) -> float:
    """Wall seconds until ``cond()`` is true, or NaN after ``limit_s``."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < limit_s:
        if await cond():
            return time.monotonic() - t0
        await asyncio.sleep(poll_s)
    return math.nan


async def freeze_crash_async(repeats: int = 10, freeze_s: float = 3.0) -> dict[str, Any]:
    stalls: list[str] = []
    freeze_recovery: list[float] = []
    crash_recovery: list[float] = []
    noticed: list[float] = []
    async with stack(FAIL_SPEED, supervisor=True, retain=True) as (st, logins):
        sup = Probe(st.supervisor_url, ("Supervisor.PlcConnected", "Supervisor.Cycle"), logins)
        plc = Probe(st.plc_url, ("PLC.Supervisor.Alive",), logins)

        async def cycle() -> int:
            got = await sup.read()
            return int(got["Supervisor.Cycle"]) if got is not None else -1

        async def disconnected() -> bool:
            got = await sup.read()
            return got is not None and not got["Supervisor.PlcConnected"]

        def recovered_past(before: int) -> Callable[[], Awaitable[bool]]:
            async def cond() -> bool:
                got = await sup.read()
                if got is None or not got["Supervisor.PlcConnected"] or got["Supervisor.Cycle"] <= before:
                    return False
                return bool(await plc.value("PLC.Supervisor.Alive"))

            return cond

        async def wait_recovery(before: int, what: str, into: list[float]) -> None:
            back = await _until(recovered_past(before), RECOVERY_LIMIT_S)
            if math.isnan(back):
                stalls.append(f"{what}: no recovery within {RECOVERY_LIMIT_S:g} s")
            else:
                into.append(back)

        try:
            if math.isnan(await _until(recovered_past(0), RECOVERY_LIMIT_S, 0.2)):
                raise RuntimeError("the supervisor never cycled with the PLC")
            for rep in range(repeats):
                plc_pid = st.pid("plc")
                # Freeze for freeze_s of wall time; the supervisor must notice.
                before = await cycle()
                os.kill(plc_pid, signal.SIGSTOP)
                try:
                    seen = await _until(disconnected, freeze_s)
                    if not math.isnan(seen):
                        noticed.append(seen)
                        await asyncio.sleep(freeze_s - seen)
                    else:
                        stalls.append(
                            f"repeat {rep}: PlcConnected stayed True through a {freeze_s:g} s freeze"
                        )
                finally:
                    os.kill(plc_pid, signal.SIGCONT)
                await plc.close()
                await wait_recovery(
                    max(before, await cycle()), f"repeat {rep}, after SIGCONT", freeze_recovery
                )
                # Crash, and a restart on the same port with the same retentive memory.
                await st.kill("plc")
                await plc.close()
                seen = await _until(disconnected, 30.0)
                if math.isnan(seen):
                    stalls.append(f"repeat {rep}: PlcConnected stayed True for 30 s after the PLC died")
                else:
                    noticed.append(seen)
                before = await cycle()
                await st.start("plc")
                await wait_recovery(before, f"repeat {rep}, after the restart", crash_recovery)
        finally:
            await sup.close()
            await plc.close()
    return {
        "repeats": repeats,
        "freeze_s": freeze_s,
        "speed": FAIL_SPEED,
        "silent_stalls": len(stalls),
        "stalls": stalls,
        "noticed_s": Summary.of(noticed).__dict__,
        "freeze_recovery_s": Summary.of(freeze_recovery).__dict__,
        "crash_recovery_s": Summary.of(crash_recovery).__dict__,
    }


def freeze_crash(repeats: int = 10) -> dict[str, Any]:
    """Freeze-then-crash of the PLC under a running supervisor (see the module docstring)."""
    return asyncio.run(freeze_crash_async(repeats))


# ---- parked sockets --------------------------------------------------------------------------


async def idle_sockets_async(n: int = 200) -> dict[str, Any]:
    async with stack(FUZZ_SPEED) as (st, logins):
        # A first session warms the server up (and proves it serves).
        async with session(st.plc_url, logins, "engineer") as client:
            await read_scan(client)
        loop = asyncio.get_running_loop()
        parked: list[tuple[asyncio.StreamReader, asyncio.StreamWriter, float]] = []
        refused = 0
        for _ in range(n):
            try:
                r, w = await asyncio.open_connection(HOST, st.base + 1)
                parked.append((r, w, loop.time()))
            except OSError:
                refused += 1

        async def closed_after(r: asyncio.StreamReader, opened: float) -> float:
            try:
                data = await asyncio.wait_for(r.read(1), 30.0)
            except TimeoutError:
                return math.nan
            except ConnectionError:
                data = b""
            return loop.time() - opened if not data else math.nan

        watchers = [asyncio.create_task(closed_after(r, t)) for r, _, t in parked]
        t0 = time.perf_counter()
        connect_read_s = math.nan
        error = ""
        try:
            async with session(st.plc_url, logins, "engineer") as client:
                await read_scan(client)
                connect_read_s = time.perf_counter() - t0
        except Exception as e:
            error = f"{type(e).__name__}: {e}"
        close_s = await asyncio.gather(*watchers)
        for _, w, _ in parked:
            w.close()
    closed = [c for c in close_s if math.isfinite(c)]
    return {
        "n": n,
        "refused_at_connect": refused,
        "connect_read_s": connect_read_s,
        "connect_target_s": 1.0,
        "error": error,
        "closed": len(closed),
        "close_s": Summary.of(closed).__dict__,
        "handshake_limit_s": LIMITS.handshake_s,
    }


def idle_sockets(n: int = 200) -> dict[str, Any]:
    """Parked sockets against a legitimate client (see the module docstring)."""
    return asyncio.run(idle_sockets_async(n))


# ---- failed logins ---------------------------------------------------------------------------


async def login_storm_async(n: int = 48, concurrency: int = 8) -> dict[str, Any]:
    async with stack(FLOOD_SPEED) as (st, logins), session(st.plc_url, logins, "engineer") as watcher:

        async def failed_login(k: int) -> None:
            client = new_client(st.plc_url, 10.0)
            who = ClientIdentity(logins.home, "cli", Credentials(f"nobody{k}", "not-the-password"))
            await secure_client(client, who)
            with contextlib.suppress(Exception):
                await client.connect()
            await quiet_disconnect(client)

        before = await status_after_scans(watcher, 2)
        started = time.perf_counter()
        for burst in range(0, n, concurrency):
            await asyncio.gather(*(failed_login(k) for k in range(burst, min(n, burst + concurrency))))
        wall = time.perf_counter() - started
        after = await status_after_scans(watcher, 2)
    return {
        "logins": n,
        "concurrency": concurrency,
        "speed": FLOOD_SPEED,
        "wall_s": wall,
        "overruns": int(after["Overruns"]) - int(before["Overruns"]),
    }


def login_storm(n: int = 48, concurrency: int = 8) -> dict[str, Any]:
    """Failed password logins (unknown user names, in bursts of ``concurrency``) against the
    PLC at speed 5: the overruns they cause (see the module docstring of ``tests/robustness/
    test_flood.py``)."""
    return asyncio.run(login_storm_async(n, concurrency))


# ---- all, and the report ---------------------------------------------------------------------


def run_all(full: bool = True) -> dict[str, Any]:
    """Every robustness benchmark, full size (``make bench``) or small; a failing one is
    reported under ``errors`` and the others still run."""
    plan: dict[str, Callable[[], dict[str, Any]]] = {
        "fuzz": lambda: fuzz(5000 if full else 500),
        "flood": lambda: flood(60.0 if full else 10.0),
        "freeze_crash": lambda: freeze_crash(10 if full else 2),
        "idle_sockets": lambda: idle_sockets(200),
        "login_storm": lambda: login_storm(48 if full else 24),
    }
    out: dict[str, Any] = {"full": full, "errors": []}
    for name, body in plan.items():
        try:
            out[name] = body()
        except Exception as e:
            out["errors"].append(f"{name}: {type(e).__name__}: {e}")
    return out


def _summary_ms(s: dict[str, Any]) -> str:
    if not s or not s.get("n"):
        return "n/a"
    return f"median {fmt(1e3 * s['median'])} ms, max {fmt(1e3 * s['maximum'])} ms (n = {s['n']})"


def _summary_s(s: dict[str, Any]) -> str:
    if not s or not s.get("n"):
        return "n/a"
    return f"median {fmt(s['median'])} s, max {fmt(s['maximum'])} s (n = {s['n']})"


def _counts(c: dict[str, int]) -> str:
    return ", ".join(f"{k} {v:,}" for k, v in c.items()) or "none"


def _fuzz_md(fz: dict[str, Any]) -> list[str]:
    post = fz["post"]
    lines = [
        f"### Protocol fuzz ({fz['n_cases']:,} cases, seed {fz['seed']}, PLC at speed {fz['speed']:g})",
        "",
        "| kind | cases | closed by the server | first answers |",
        "|---|---:|---:|---|",
    ]
    for kind in (*RAW_KINDS, *SESSION_KINDS):
        if kind not in fz["cases"]:
            continue
        name = f"{kind} (must close)" if kind in MUST_CLOSE else kind
        if kind in RAW_KINDS:
            closed = str(fz["closed"].get(kind, 0))
            answers = {k.split(":", 1)[1]: v for k, v in fz["replies"].items() if k.startswith(kind + ":")}
            lines.append(f"| {name} | {fz['cases'][kind]:,} | {closed} | {_counts(answers)} |")
        else:
            lines.append(f"| {name} | {fz['cases'][kind]:,} | | |")
    out_of_contract = post["out_of_contract"]
    lines += [
        "",
        f"Typed requests, answers by status: {_counts(fz['statuses'])}.",
        "",
        f"- Oracle violations (accepted although the contract refuses, must-close left open):"
        f" **{len(fz['violations'])}**"
        + (f" ({'; '.join(fz['violations'][:5])})" if fz["violations"] else ""),
        f"- Admissible requests the PLC refused from its state (e.g. SetGains before the supervisor"
        f" is trusted): {fz['admissible_refused']:,}",
        f"- Accepted although OPC UA says no (not a tanklab contract violation):"
        f" {_counts(fz.get('findings', {}))}",
        f"- Connections closed by the server: {_summary_ms(fz['close_s'])} after the last byte",
        f"- After the fuzz: alive {post['alive']}, a Read Good {post['read_good']}, stored values outside"
        f" their contract **{len(out_of_contract)}**, scan counter {post['scan_before']} ->"
        f" {post['scan_after']}" + (f" ({post['error']})" if post["error"] else ""),
        f"- Wall time {fmt(fz['wall_s'])} s; cases that could not be sent: {_counts(fz['failed'])}",
        "",
    ]
    return lines


def _flood_md(fl: dict[str, Any]) -> list[str]:
    overruns = fl["overruns_after"] - fl["overruns_before"]
    return [
        f"### Write flood ({fl['clients']} engineer sessions, {fl['seconds']:g} s,"
        f" PLC at speed {fl['speed']:g})",
        "",
        "| writes/s | accepted/s | refused/s | overruns | scans (expected) | PLC lag behind the plant |"
        " largest scan | lateness p50 / p99 |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
        f"| {fmt(fl['writes_per_s'])} | {fmt(fl['accepted_per_s'])} | {fmt(fl['refused_per_s'])} |"
        f" {overruns} | {fl['scans']} ({fmt(fl['scans_expected'])}) | {fmt(fl['model_lag_s'])} s |"
        f" {fmt(fl['max_scan_duration_ms'])} ms |"
        f" {fmt(fl['lateness_p50_ms'])} / {fmt(fl['lateness_p99_ms'])} ms |",
        "",
        f"Answers by status: {_counts(fl['statuses'])}. Invalid writes accepted: **{len(fl['violations'])}**."
        + (f" Errors: {'; '.join(fl['errors'])}." if fl["errors"] else "")
        + " Lateness: start of each scan minus its deadline, over the PLC's whole run.",
        "",
    ]


def _freeze_md(fc: dict[str, Any]) -> list[str]:
    stalls = f" ({'; '.join(fc['stalls'])})" if fc["stalls"] else ""
    return [
        f"### Freeze then crash of the PLC under a running supervisor ({fc['repeats']} repeats,"
        f" speed {fc['speed']:g})",
        "",
        f"SIGSTOP for {fc['freeze_s']:g} s, SIGCONT, then SIGKILL and a restart on the same port with",
        "the same retentive memory. Silent stalls (the supervisor kept reporting the PLC connected",
        f"while it was away, or did not recover within {RECOVERY_LIMIT_S:g} s):"
        f" **{fc['silent_stalls']}**{stalls}.",
        "Recovered: PlcConnected True, Supervisor.Cycle past its value before the fault,",
        "PLC.Supervisor.Alive True.",
        "",
        "| | wall time |",
        "|---|---|",
        f"| PLC loss noticed (PlcConnected False) | {_summary_s(fc['noticed_s'])} |",
        f"| recovery after SIGCONT | {_summary_s(fc['freeze_recovery_s'])} |",
        f"| recovery after the restarted PLC serves | {_summary_s(fc['crash_recovery_s'])} |",
        "",
    ]


def _idle_md(idle: dict[str, Any]) -> list[str]:
    ok = math.isfinite(idle["connect_read_s"]) and idle["connect_read_s"] <= idle["connect_target_s"]
    return [
        f"### Parked sockets ({idle['n']} TCP connections without a Hello)",
        "",
        f"- A legitimate secure client connected and read in {fmt(idle['connect_read_s'])} s"
        f" (target <= {idle['connect_target_s']:g} s: {'met' if ok else '**not met**'})"
        + (f"; error: {idle['error']}" if idle["error"] else ""),
        f"- Parked sockets closed by the server: {idle['closed']} of {idle['n']},"
        f" {_summary_s(idle['close_s'])} after connecting (handshake limit {idle['handshake_limit_s']:g} s);"
        f" refused at connect: {idle['refused_at_connect']}",
        "",
    ]


def _logins_md(ls: dict[str, Any]) -> list[str]:
    return [
        f"### Failed password logins ({ls['logins']} unknown user names, {ls['concurrency']} at a time,"
        f" PLC at speed {ls['speed']:g})",
        "",
        f"Scan overruns caused: **{ls['overruns']}** in {fmt(ls['wall_s'])} s. The password check",
        "(scrypt, about 70 ms) runs in a worker thread before asyncua's synchronous user lookup, and",
        "past ten failures a minute (any names) password checks are suspended for the window.",
        "",
    ]


def markdown(results: dict[str, Any]) -> str:
    """The robustness section of ``docs/benchmarks.md``."""
    lines = [
        "## 8. Robustness of the secured PLC server",
        "",
        "Real plant and PLC processes (and the supervisor for freeze-then-crash) on loopback, secured",
        "with a fresh PKI and an engineer login, tanks starting at the operating point;",
        "`benchmarks/security.py`, with the generators and oracles of `tanklab_testing.security`",
        "(CI-sized twins in `tests/robustness/`).",
        "",
    ]
    sections: list[tuple[str, Callable[[dict[str, Any]], list[str]]]] = [
        ("fuzz", _fuzz_md),
        ("flood", _flood_md),
        ("freeze_crash", _freeze_md),
        ("idle_sockets", _idle_md),
        ("login_storm", _logins_md),
    ]
    for key, render in sections:
        if results.get(key):
            lines += render(results[key])
    for err in results.get("errors", []):
        lines.append(f"- error: {err}")
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":
    import json
    import sys

    which = sys.argv[1] if len(sys.argv) > 1 else "all"
    res = run_all(full=False) if which == "all" else {which: globals()[which]()}
    print(json.dumps(res, indent=1, default=str))
    print(markdown(res))
