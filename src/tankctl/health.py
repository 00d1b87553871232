"""Health probe of a tier: one OPC UA read, one line of output, exit 0 or 1.

    python -m tankctl.health opc.tcp://HOST:PORT/tanklab/plant [--path Plant.Sim.Time] [--timeout 3]

Used by the docker compose healthchecks (and usable from any shell). The probe connects
encrypted with the tier's own certificate from the security home (``--home``, env
``TANKLAB_HOME``) as its X509 identity, which every tier's server accepts as an Observer of
itself; it looks up the namespace index of ``urn:tanklab`` (never hard-coded), reads the Value
of one node and reports:

- exit 0 and ``ok URL PATH = VALUE`` on stdout when the read's StatusCode is Good;
- exit 1 and ``tankctl.health: URL: REASON`` on stderr otherwise: no answer within the
  timeout, connection refused, namespace or node unknown, a Bad or Uncertain status, or a
  usage error (Docker reads 0 as healthy and 1 as unhealthy; 2 is reserved, so usage errors
  exit 1 too).

Nothing prints a traceback, and asyncua's own log records are silenced so the one line is
the whole output. The default node depends on the tier named by the URL's last path element:
a value each tier updates while it runs.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from pathlib import Path
from typing import Any, NoReturn

from asyncua import ua

from tanklab.paths import PROBE_PATHS
from tanklab_io.home import SecurityHome, default_home
from tanklab_io.ua_client import new_client, resolve
from tanklab_io.ua_client_security import ClientIdentity, secure_client

DEFAULT_PATHS = PROBE_PATHS
"""Node read by default, keyed by the URL's last path element (the tier)."""

DEFAULT_TIMEOUT_S = 3.0
"""Wall-time bound of the whole probe: connect, namespace lookup, read and disconnect [s]."""

PROG = "tankctl.health"


class ProbeError(Exception):
    """The tier did not answer the probe with a Good value; the message is the one line."""


def default_path(url: str) -> str:
    """Node path to read for ``url``, chosen by its last path element.

    Raises
    ------
    ValueError
        If the last path element is not ``plant``, ``plc`` or ``supervisor``.
    """
    tier = url.rstrip("/").rsplit("/", 1)[-1]
    try:
        return DEFAULT_PATHS[tier]
    except KeyError:
        raise ValueError(
            f"cannot tell the tier from the URL's last path element {tier!r}: "
            f"expected one of {', '.join(DEFAULT_PATHS)}, or pass --path"
        ) from None


async def read_once(
    url: str, path: str, identity: ClientIdentity, timeout_s: float = DEFAULT_TIMEOUT_S
) -> Any:
    """Connect to ``url``, read node ``path`` of namespace ``urn:tanklab`` and return its value.

    Parameters
    ----------
    url
        ``opc.tcp://HOST:PORT/...`` endpoint of a tier.
    path
        Dotted tag path (the string NodeId), e.g. ``Plant.Sim.Time``.
    identity
        Who connects (the tier's own certificate, or the CLI with a login).
    timeout_s
        Bound on the whole exchange [s of wall time].

    Raises
    ------
    ProbeError
        On any failure, with a one-line reason.
    """

    async def exchange() -> Any:
        client = new_client(url, timeout_s)
        await secure_client(client, identity)
        async with client:
            try:
                nodes = await resolve(client, [path])
            except ValueError:
                raise ProbeError("the server does not register namespace urn:tanklab") from None
            (dv,) = await client.read_attributes([nodes[path]])
            status = dv.StatusCode or ua.StatusCode(ua.StatusCodes.Good)
            if not status.is_good():
                raise ProbeError(f"{path}: {status.name}")
            return dv.Value.Value if dv.Value is not None else None

    try:
        return await asyncio.wait_for(exchange(), timeout_s)
    except ProbeError:
        raise
    except TimeoutError:
        raise ProbeError(f"no answer within {timeout_s:g} s") from None
    except ua.UaStatusCodeError as e:
        raise ProbeError(f"{path}: {ua.StatusCode(e.code).name}") from None
    except OSError as e:
        raise ProbeError(f"cannot connect: {e.strerror or e}") from None
    except Exception as e:  # the probe's boundary: any failure is "unhealthy", told in one line
        raise ProbeError(f"{type(e).__name__}: {e}" if str(e) else type(e).__name__) from None


def _short(value: Any, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors as one line and exit code 1 (Docker reserves 2)."""

    def error(self, message: str) -> NoReturn:
        print(f"{PROG}: {message}", file=sys.stderr)
        raise SystemExit(1)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog=f"python -m {PROG}", description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("url", help="Endpoint, e.g. opc.tcp://localhost:4840/tanklab/plant.")
    p.add_argument(
        "--path",
        help="Node to read (default by tier: "
        + ", ".join(f"{tier} {path}" for tier, path in DEFAULT_PATHS.items())
        + ").",
    )
    p.add_argument("--home", help="Security home (default: env TANKLAB_HOME, else ~/.config/tanklab).")
    p.add_argument(
        "--timeout",
        type=float,
        default=DEFAULT_TIMEOUT_S,
        help=f"Bound on the whole probe in seconds (default {DEFAULT_TIMEOUT_S:g}).",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the probe; return the exit code (0 Good read, 1 anything else)."""
    args = _parser().parse_args(argv)
    url: str = args.url
    # asyncua and asyncio log to the last-resort stderr handler when nothing is configured;
    # a NullHandler on the root keeps the probe's output to its one line.
    logging.getLogger().addHandler(logging.NullHandler())
    if not url.startswith("opc.tcp://"):
        print(f"{PROG}: {url}: not an opc.tcp:// URL", file=sys.stderr)
        return 1
    if not (args.timeout > 0):
        print(f"{PROG}: --timeout must be a positive number of seconds, got {args.timeout}", file=sys.stderr)
        return 1
    try:
        path = args.path or default_path(url)
        tier = url.rstrip("/").rsplit("/", 1)[-1]
        home = SecurityHome(Path(args.home) if args.home else default_home())
        value = asyncio.run(read_once(url, path, ClientIdentity(home, tier), args.timeout))
    except (ValueError, ProbeError) as e:
        print(f"{PROG}: {url}: {e}", file=sys.stderr)
        return 1
    print(f"ok {url} {path} = {_short(value)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
