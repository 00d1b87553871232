"""The PLC and the plant as real processes on loopback (speed 20), driven by a real client.

Assertions are on model time (``PLC.Status.ModelTime``, ``PLC.Status.Scan``); waiting for the
processes goes through ``wait_until`` only.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from asyncua import ua

from helpers import ROOT, TierProcess, free_port, secure, wait_until
from tanklab_io.ua_client import read_values, resolve

CONFIG = str(ROOT / "configs/three_tank_energies_sim.yaml")
SPEED = "20"
pytestmark = pytest.mark.process


@pytest.fixture
async def stack(tmp_path: Path):
    pp, cp = free_port(), free_port()
    plant_url = f"opc.tcp://127.0.0.1:{pp}/tanklab/plant"
    state = str(tmp_path / "plant.json")
    plant = await TierProcess(
        "plant", "--config", CONFIG, "--port", str(pp), "--speed", SPEED, "--state-file", state
    ).start()
    plc = await TierProcess(
        "plc", "--config", CONFIG, "--port", str(cp), "--plant-url", plant_url, "--speed", SPEED
    ).start()
    procs = {"plant": plant, "plc": plc, "plant_args": (pp, state)}
    yield procs, f"opc.tcp://127.0.0.1:{cp}/tanklab/plc"
    for p in (procs["plc"], procs["plant"]):
        await p.stop()


PATHS = [
    "PLC.LIC1.SP",
    "PLC.LIC1.PV",
    "PLC.LIC1.MV",
    "PLC.LIC1.Mode",
    "PLC.LIC1.ManualMV",
    "PLC.LIC1.RemoteMV",
    "PLC.LIC1.Kp",
    "PLC.LIC1.GainSource",
    "PLC.LIC2.PV",
    "PLC.Status.Scan",
    "PLC.Status.IoHealthy",
    "PLC.Status.ModelTime",
    "PLC.Supervisor.Heartbeat",
    "PLC.Supervisor.Alive",
    "PLC.Alarms.IoFault",
]


async def test_plc_tracks_a_setpoint_step_through_the_real_plant(stack) -> None:
    _, url = stack
    async with await secure(url) as client:
        n = await resolve(client, PATHS)

        # From empty tanks the fixed PIDs fill T1 to 0.4 m; then step the setpoint to 0.3 m.
        async def settled_at(sp: float) -> bool:
            pv = await n["PLC.LIC1.PV"].read_value()
            return abs(pv - sp) < 0.01

        await wait_until(lambda: settled_at(0.4), 60, what="T1 at 0.4 m")
        t_step = await n["PLC.Status.ModelTime"].read_value()
        await n["PLC.LIC1.SP"].write_value(ua.Variant(0.3, ua.VariantType.Double))
        await wait_until(lambda: settled_at(0.3), 60, what="T1 at the new setpoint 0.3 m")
        t_reached = await n["PLC.Status.ModelTime"].read_value()
        # The level falls by outflow only (the pump at its lower limit): 0.1 m in model time
        # bounded below by At * dh / q13 and above by the plant's slowest mode times a few.
        assert 20.0 < t_reached - t_step < 900.0
        assert await n["PLC.Status.IoHealthy"].read_value() is True


async def test_bad_writes_are_refused_and_values_stay(stack) -> None:
    _, url = stack
    async with await secure(url) as client:
        n = await resolve(client, PATHS)
        cases = [
            ("PLC.LIC1.SP", ua.Variant(0.61, ua.VariantType.Double), "BadOutOfRange"),
            ("PLC.LIC1.SP", ua.Variant(-0.1, ua.VariantType.Double), "BadOutOfRange"),
            ("PLC.LIC1.SP", ua.Variant(float("nan"), ua.VariantType.Double), "BadOutOfRange"),
            ("PLC.LIC1.SP", ua.Variant(float("-inf"), ua.VariantType.Double), "BadOutOfRange"),
            ("PLC.LIC1.SP", ua.Variant(1, ua.VariantType.Int32), "BadTypeMismatch"),
            ("PLC.LIC1.Mode", ua.Variant(3, ua.VariantType.Int32), "BadOutOfRange"),
            ("PLC.LIC1.Mode", ua.Variant(1.0, ua.VariantType.Double), "BadTypeMismatch"),
            ("PLC.LIC1.ManualMV", ua.Variant(2e-4, ua.VariantType.Double), "BadOutOfRange"),
            ("PLC.LIC1.ManualMV", ua.Variant(float("nan"), ua.VariantType.Double), "BadOutOfRange"),
            ("PLC.LIC1.RemoteMV", ua.Variant(1e-5, ua.VariantType.Double), "BadUserAccessDenied"),
            ("PLC.LIC1.Kp", ua.Variant(1e-3, ua.VariantType.Double), "BadNotWritable"),
            ("PLC.LIC1.GainSource", ua.Variant(1, ua.VariantType.Int32), "BadNotWritable"),
            ("PLC.Supervisor.Heartbeat", ua.Variant(7, ua.VariantType.UInt32), "BadUserAccessDenied"),
        ]
        for path, value, expected in cases:
            before = await n[path].read_value()
            with pytest.raises(ua.UaStatusCodeError) as err:
                await n[path].write_value(value)
            assert type(err.value).__name__ == expected, (path, value)
            if path not in ("PLC.LIC1.Kp", "PLC.LIC1.GainSource"):  # these the scan republishes
                assert await n[path].read_value() == before, path
        # SetGains: outside the box, not finite, wrong type (an engineer's call needs no trusted
        # supervisor: test_engineer_gains_release_and_reset_through_the_real_server).
        idx = n["PLC.LIC1.SP"].nodeid.NamespaceIndex
        obj = client.get_node(ua.NodeId("PLC.LIC1", idx))
        method = ua.NodeId("PLC.LIC1.SetGains", idx)
        kp_before = await n["PLC.LIC1.Kp"].read_value()
        for args, expected in (
            ((1.0, 1e-5, 0.0), "BadOutOfRange"),
            ((float("nan"), 1e-5, 0.0), "BadOutOfRange"),
            ((1e-3, 1e-5, float("inf")), "BadOutOfRange"),
            ((ua.Variant(1, ua.VariantType.Int32), 1e-5, 0.0), "BadTypeMismatch"),
            ((1e-3, 1e-5), "BadArgumentsMissing"),
        ):
            with pytest.raises(ua.UaStatusCodeError) as err:
                await obj.call_method(method, *args)
            assert type(err.value).__name__ == expected, args
        assert await n["PLC.LIC1.Kp"].read_value() == kp_before
    # The supervisor's own nodes get the contract's checks when the supervisor writes them.
    async with await secure(url, tier="supervisor") as sup:
        n = await resolve(sup, ["PLC.LIC1.RemoteMV", "PLC.Supervisor.Heartbeat", "PLC.LIC1.SP"])
        for path, value, expected in (
            ("PLC.LIC1.RemoteMV", ua.Variant(-1e-5, ua.VariantType.Double), "BadOutOfRange"),
            ("PLC.Supervisor.Heartbeat", ua.Variant(1.5, ua.VariantType.Double), "BadTypeMismatch"),
            ("PLC.LIC1.SP", ua.Variant(0.3, ua.VariantType.Double), "BadUserAccessDenied"),
        ):
            before = await n[path].read_value()
            with pytest.raises(ua.UaStatusCodeError) as err:
                await n[path].write_value(value)
            assert type(err.value).__name__ == expected, (path, value)
            assert await n[path].read_value() == before, path
        # The supervisor's own SetGains is refused while it is not trusted (no heartbeat yet).
        assert await _call(sup, "SetGains", 1e-3, 1e-5, 0.0) == "BadInvalidState"


async def test_heartbeat_gains_and_fallback_within_timeout_plus_one_scan(stack) -> None:
    _, url = stack
    async with await secure(url, tier="supervisor") as client:
        n = await resolve(client, PATHS)
        idx = n["PLC.LIC1.SP"].nodeid.NamespaceIndex
        obj = client.get_node(ua.NodeId("PLC.LIC1", idx))
        beat = 0

        async def beat_and_check_trusted() -> bool:
            nonlocal beat
            beat += 1
            await n["PLC.Supervisor.Heartbeat"].write_value(ua.Variant(beat, ua.VariantType.UInt32))
            try:
                await obj.call_method(ua.NodeId("PLC.LIC1.SetGains", idx), 8.0e-4, 8.0e-6, -1.0e-4)
            except ua.UaStatusCodeError:
                return False
            return True

        await wait_until(beat_and_check_trusted, 30, what="SetGains accepted after good heartbeats")

        async def applied() -> bool:
            await n["PLC.Supervisor.Heartbeat"].write_value(ua.Variant(beat, ua.VariantType.UInt32))
            return await n["PLC.LIC1.GainSource"].read_value() == 1

        await wait_until(applied, 20, what="supervisor gains applied")
        assert await n["PLC.LIC1.Kp"].read_value() == pytest.approx(8.0e-4)
        # Last heartbeat change: write a new value and note the model time of the next scan.
        beat += 1
        await n["PLC.Supervisor.Heartbeat"].write_value(ua.Variant(beat, ua.VariantType.UInt32))
        scan0 = await n["PLC.Status.Scan"].read_value()
        await wait_until(lambda: _scan_after(n, scan0), 10, what="a scan after the last heartbeat")
        t_last = await n["PLC.Status.ModelTime"].read_value()

        async def fell_back() -> bool:
            return await n["PLC.LIC1.GainSource"].read_value() == 2

        await wait_until(fell_back, 30, what="FALLBACK after heartbeat loss")
        t_fb = await n["PLC.Status.ModelTime"].read_value()
        # Timeout is max(3 s, 1 s wall * speed 20) = 20 s model; one scan is 1 s.
        timeout = 20.0
        assert t_fb - t_last <= timeout + 1.0 + 1.0  # + the scan between our two reads
        assert await n["PLC.Supervisor.Alive"].read_value() is False
        assert await n["PLC.LIC1.Kp"].read_value() == pytest.approx(4.29e-4)  # fallback: fixed gains


async def _scan_after(n, scan0: int) -> bool:
    return await n["PLC.Status.Scan"].read_value() > scan0


async def test_plant_killed_and_restarted_plc_reports_reconnects_and_regulates(stack) -> None:
    procs, url = stack
    async with await secure(url) as client:
        n = await resolve(client, PATHS)

        async def near_sp() -> bool:
            return abs(await n["PLC.LIC1.PV"].read_value() - 0.4) < 0.02

        await wait_until(near_sp, 60, what="T1 near 0.4 m before the plant is killed")
        await procs["plant"].kill()

        async def io_lost() -> bool:
            return await n["PLC.Status.IoHealthy"].read_value() is False

        await wait_until(io_lost, 20, what="IoHealthy false after the plant died")
        assert await n["PLC.Alarms.IoFault"].read_value() is True
        scans = await n["PLC.Status.Scan"].read_value()
        await wait_until(lambda: _scan_after(n, scans + 5), 10, what="the PLC keeps scanning without a plant")
        pp, state = procs["plant_args"]
        procs["plant"] = await TierProcess(
            "plant", "--config", CONFIG, "--port", str(pp), "--speed", SPEED, "--state-file", state
        ).start()

        async def io_back() -> bool:
            return await n["PLC.Status.IoHealthy"].read_value() is True

        await wait_until(io_back, 30, what="IoHealthy true after the plant returned")
        t_back = await n["PLC.Status.ModelTime"].read_value()

        async def regulating() -> bool:
            t = await n["PLC.Status.ModelTime"].read_value()
            return t - t_back > 60 and abs(await n["PLC.LIC1.PV"].read_value() - 0.4) < 0.02

        await wait_until(regulating, 60, what="T1 regulated near 0.4 m after the restart")


async def test_plc_warm_restart_keeps_setpoint_and_mode(tmp_path: Path) -> None:
    import yaml

    data = yaml.safe_load(Path(CONFIG).read_text())
    data["plc"]["retain_file"] = str(tmp_path / "plc-retain.json")
    config = tmp_path / "site.yaml"
    config.write_text(yaml.safe_dump(data))
    pp, cp = free_port(), free_port()
    plant_url = f"opc.tcp://127.0.0.1:{pp}/tanklab/plant"
    plant = await TierProcess("plant", "--config", str(config), "--port", str(pp), "--speed", SPEED).start()
    args = ("plc", "--config", str(config), "--port", str(cp), "--plant-url", plant_url, "--speed", SPEED)
    plc = await TierProcess(*args).start()
    url = f"opc.tcp://127.0.0.1:{cp}/tanklab/plc"
    try:
        async with await secure(url) as client:
            n = await resolve(client, ["PLC.LIC1.SP", "PLC.LIC2.Mode"])
            await n["PLC.LIC1.SP"].write_value(ua.Variant(0.35, ua.VariantType.Double))
            await n["PLC.LIC2.Mode"].write_value(ua.Variant(0, ua.VariantType.Int32))  # MANUAL

            async def retained() -> bool:
                p = tmp_path / "plc-retain.json"
                if not p.exists():
                    return False
                try:
                    loops = json.loads(p.read_text())["loops"]
                except ValueError:  # caught between write and rename: not yet
                    return False
                return loops["LIC2"]["mode"] == "MANUAL" and loops["LIC1"]["sp_m"] == 0.35

            await wait_until(retained, 20, what="the retentive memory written")
        assert await plc.stop() == 0
        plc = await TierProcess(*args).start()
        async with await secure(url) as client:
            n = await resolve(client, ["PLC.LIC1.SP", "PLC.LIC2.Mode"])
            assert await n["PLC.LIC1.SP"].read_value() == 0.35
            assert await n["PLC.LIC2.Mode"].read_value() == 0
    finally:
        await plc.stop()
        await plant.stop()


# --------------------------------------------------------------------------- gain sources
GAIN_PATHS = [
    "PLC.Status.Scan",
    "PLC.LIC1.SP",
    "PLC.LIC1.PV",
    "PLC.LIC1.MV",
    "PLC.LIC1.Kp",
    "PLC.LIC1.Ki",
    "PLC.LIC1.Kd",
    "PLC.LIC1.GainSource",
    "PLC.Supervisor.Heartbeat",
]
FIXED_GAINS = (4.29e-4, 5.32e-6, -1.42e-4)  # three_tank_energies_sim.yaml, LIC1 (digest 2.1)
ENGINEER_GAINS = (8.0e-4, 8.0e-6, -1.0e-4)


async def _call(client, name: str, *args) -> str:
    """Call PLC.LIC1.<name>(*args); the status code's name."""
    idx = await client.get_namespace_index("urn:tanklab")
    obj = client.get_node(ua.NodeId("PLC.LIC1", idx))
    try:
        await obj.call_method(ua.NodeId(f"PLC.LIC1.{name}", idx), *args)
    except ua.UaStatusCodeError as e:
        return type(e).__name__
    return "Good"


async def _source_and_gains(n) -> tuple[int, tuple[float, float, float]]:
    paths = ("PLC.LIC1.GainSource", "PLC.LIC1.Kp", "PLC.LIC1.Ki", "PLC.LIC1.Kd")
    values = [await n[p].read_value() for p in paths]
    return values[0], (values[1], values[2], values[3])


async def test_engineer_gains_release_and_reset_through_the_real_server(stack) -> None:
    _, url = stack
    async with (
        await secure(url) as eng,
        await secure(url, "operator") as op,
        await secure(url, "observer") as obs,
        await secure(url, tier="supervisor") as sup,
    ):
        n = await resolve(eng, GAIN_PATHS)
        await wait_until(lambda: _near_sp(n), 60, what="T1 regulated near its setpoint (MV inside its range)")
        # An Observer may call none of the three.
        for name, args in (("SetGains", ENGINEER_GAINS), ("ResetGains", ()), ("ReleaseGains", ())):
            assert await _call(obs, name, *args) == "BadUserAccessDenied", name
        # The engineer's SetGains works with no supervisor at all and is labelled ENGINEER (3).
        assert await _call(eng, "SetGains", *ENGINEER_GAINS) == "Good"

        async def engineer_applied() -> bool:
            return await _source_and_gains(n) == (3, ENGINEER_GAINS)

        await wait_until(engineer_applied, 20, what="ENGINEER gains applied")
        # NaN and out-of-box gains are refused whole; the engineer's gains stay.
        for bad in ((float("nan"), 8e-6, 0.0), (1.0, 8e-6, 0.0), (8e-4, 8e-6, float("inf"))):
            assert await _call(eng, "SetGains", *bad) == "BadOutOfRange", bad
        # The supervisor, alive and trusted, is refused on the held loop.
        s = await resolve(sup, ["PLC.Supervisor.Heartbeat", "PLC.Supervisor.Alive"])
        beat = 0

        async def heartbeat() -> None:
            nonlocal beat
            beat += 1
            await s["PLC.Supervisor.Heartbeat"].write_value(ua.Variant(beat, ua.VariantType.UInt32))

        async def alive_for_a_while() -> bool:
            await heartbeat()
            return beat > 40 and await s["PLC.Supervisor.Alive"].read_value() is True

        await wait_until(alive_for_a_while, 20, what="the supervisor alive for several scans")
        assert await _call(sup, "SetGains", *FIXED_GAINS) == "BadInvalidState"
        await heartbeat()
        await _scans_later(n, 2)
        assert await _source_and_gains(n) == (3, ENGINEER_GAINS)
        # The operator hands the loop back: the gains stay, source FIXED (0); the supervisor may
        # push again and its gains are labelled SUPERVISOR (1).
        assert await _call(op, "ReleaseGains") == "Good"
        await heartbeat()
        await _scans_later(n, 1)
        assert await _source_and_gains(n) == (0, ENGINEER_GAINS)
        supervisor_gains = (6.0e-4, 6.0e-6, -1.2e-4)

        async def supervisor_accepted() -> bool:
            await heartbeat()
            return await _call(sup, "SetGains", *supervisor_gains) == "Good"

        await wait_until(supervisor_accepted, 20, what="the supervisor's SetGains accepted after the release")

        async def supervisor_applied() -> bool:
            await heartbeat()
            return await _source_and_gains(n) == (1, supervisor_gains)

        await wait_until(supervisor_applied, 20, what="SUPERVISOR gains applied")
        # ResetGains (operator): the fixed gains at the next scan boundary, source FIXED, and the
        # scan after the boundary moves the MV by the fixed gains' own velocity-form increment.
        nodes = [
            n[p]
            for p in ("PLC.Status.Scan", "PLC.LIC1.SP", "PLC.LIC1.PV", "PLC.LIC1.MV", "PLC.LIC1.GainSource")
        ]
        samples: dict[int, tuple[float, float, float, int]] = {}

        async def record(until_fixed: bool) -> bool:
            await heartbeat()
            scan, sp, pv, mv_now, source = await read_values(eng, nodes)
            samples[int(scan)] = (float(sp), float(pv), float(mv_now), int(source))
            if not until_fixed:
                return len(samples) >= 4
            return sum(v[3] == 0 for v in samples.values()) >= 2

        await wait_until(lambda: record(False), 10, what="scans recorded before the reset", poll_s=0.002)
        assert await _call(op, "ResetGains") == "Good"
        await wait_until(lambda: record(True), 10, what="two scans on FIXED gains", poll_s=0.002)
        k = min(scan for scan, v in samples.items() if v[3] == 0)  # the first scan on FIXED gains
        assert samples[k - 1][3] == 1  # the scan before ran on the supervisor's gains
        e = {j: samples[j][0] - samples[j][1] for j in (k - 2, k - 1, k)}
        kp, ki, kd = FIXED_GAINS  # Ts = 1 s; c = 1 in this config: D on the error
        increment = kp * (e[k] - e[k - 1]) + ki * e[k] + kd * (e[k] - 2 * e[k - 1] + e[k - 2])
        mv_k, mv_prev = samples[k][2], samples[k - 1][2]
        assert 0.0 < mv_prev < 1.2e-4 and 0.0 < mv_k < 1.2e-4
        assert mv_k - mv_prev == pytest.approx(increment, rel=1e-6, abs=1e-15)
        assert await _source_and_gains(n) == (0, FIXED_GAINS)


async def _scans_later(n, count: int) -> None:
    scan0 = await n["PLC.Status.Scan"].read_value()
    await wait_until(lambda: _scan_after(n, scan0 + count - 1), 10, what=f"{count} scans")


async def _near_sp(n) -> bool:
    return abs(await n["PLC.LIC1.PV"].read_value() - await n["PLC.LIC1.SP"].read_value()) < 0.02
