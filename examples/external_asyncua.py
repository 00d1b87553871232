"""An external controller over OPC UA (asyncua): a PI in velocity form driving one PLC loop.

Needs only asyncua. Before it runs, an engineer hands the loop to it and issues its identity:

    tankctl user add-external mypi                       # certificate in role External
    tankctl loop ... / an Engineer writes PLC.LIC1.RemoteSource = EXTERNAL (1)

Then ``python examples/external_asyncua.py --url opc.tcp://127.0.0.1:4841/tanklab/plc
--home ~/.config/tanklab --name mypi --loop LIC1 --sp 0.45``. It connects with the External
certificate (SignAndEncrypt, X509 identity; the server's certificate checked against the site's
trust list and CRL), writes the heartbeat, puts the loop in REMOTE (AUTO -> REMOTE is the one mode
change role External may make), and every period reads PV and the PLC's model time and writes

    e(k) = SP - PV(k)                                            [m]
    u(k) = clamp(u(k-1) + Kp (e(k) - e(k-1)) + Ki dt(k) e(k))    [the pump's unit, e.g. m^3/s]

to ``RemoteMV`` with a new heartbeat. dt(k) is the model time between two samples [s], so the
law holds at any ``--speed``; u starts at the applied MV (bumpless). Ctrl-C (or SIGTERM) hands the
loop back to AUTO and exits 0. If this process dies instead, the PLC's watchdog sheds the loop to
AUTO once the heartbeat has not changed for its timeout.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
from pathlib import Path

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

AUTO, REMOTE = 1, 2  # PLC.LIC{j}.Mode


def parse() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--url", default="opc.tcp://127.0.0.1:4841/tanklab/plc")
    p.add_argument("--home", type=Path, default=Path.home() / ".config/tanklab", help="tanklab security home")
    p.add_argument("--name", required=True, help="the name given to `tankctl user add-external`")
    p.add_argument("--loop", default="LIC1")
    p.add_argument("--sp", type=float, required=True, help="the controller's own setpoint [m]")
    p.add_argument("--kp", type=float, default=1.5e-3, help="[MV unit per m]")
    p.add_argument("--ki", type=float, default=2.0e-5, help="[MV unit per m s]")
    p.add_argument("--period", type=float, default=0.5, help="wall-clock period [s]")
    return p.parse_args()


async def connect(args: argparse.Namespace) -> Client:
    pki = args.home / "pki"
    cert = str(pki / "own" / f"external-{args.name}.der")
    key = str(pki / "private" / f"external-{args.name}.pem")
    client = Client(args.url, timeout=10)
    client.application_uri = f"urn:tanklab:external-{args.name}"  # as in the certificate
    store = TrustStore([pki / "trusted"], [pki / "crl"])
    await store.load()
    opts = CertificateValidatorOptions
    client.certificate_validator = CertificateValidator(
        opts.TIME_RANGE | opts.URI | opts.TRUSTED | opts.REVOKED, store
    )
    await client.set_security(
        SecurityPolicyBasic256Sha256, cert, key, mode=ua.MessageSecurityMode.SignAndEncrypt
    )
    await client.load_client_certificate(cert)  # the X509 identity token: role External
    await client.load_private_key(key)
    await client.connect()
    return client


async def run(args: argparse.Namespace, stop: asyncio.Event) -> None:
    client = await connect(args)
    try:
        ns = await client.get_namespace_index("urn:tanklab")
        node = {
            k: client.get_node(ua.NodeId(p, ns))
            for k, p in {
                "pv": f"PLC.{args.loop}.PV",
                "mv": f"PLC.{args.loop}.MV",
                "mode": f"PLC.{args.loop}.Mode",
                "remote": f"PLC.{args.loop}.RemoteMV",
                "t": "PLC.Status.ModelTime",
                "beat": "PLC.External.Heartbeat",
            }.items()
        }
        rng = await (await node["remote"].get_child("0:EURange")).read_value()
        beat = await node["beat"].read_value()

        async def write(key: str, value: float | int, vtype: ua.VariantType) -> None:
            await node[key].write_value(ua.DataValue(ua.Variant(value, vtype)))

        async def heartbeat() -> None:
            nonlocal beat
            beat = (beat + 1) % 2**32
            await write("beat", beat, ua.VariantType.UInt32)

        await heartbeat()
        u = await node["mv"].read_value()
        if await node["mode"].read_value() != REMOTE:
            await write("remote", u, ua.VariantType.Double)
            await write("mode", REMOTE, ua.VariantType.Int32)
        e_prev, t_prev = None, None
        print(f"driving {args.loop} in REMOTE to SP {args.sp} m from MV {u:.4g}", flush=True)
        while not stop.is_set():
            pv, t = await node["pv"].read_value(), await node["t"].read_value()
            e = args.sp - pv
            if e_prev is not None and t > t_prev:
                u += args.kp * (e - e_prev) + args.ki * (t - t_prev) * e
                u = min(max(u, rng.Low), rng.High)
            if t_prev is None or t > t_prev:
                e_prev, t_prev = e, t
            await write("remote", u, ua.VariantType.Double)
            await heartbeat()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), args.period)
        await write("mode", AUTO, ua.VariantType.Int32)  # hand the loop back, bumpless
        print(f"{args.loop} back in AUTO", flush=True)
    finally:
        await client.disconnect()


def main() -> None:
    args = parse()

    async def body() -> None:
        stop = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            asyncio.get_running_loop().add_signal_handler(sig, stop.set)
        await run(args, stop)

    asyncio.run(body())


if __name__ == "__main__":
    main()
