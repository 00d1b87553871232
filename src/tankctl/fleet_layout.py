"""Where the sites of a fleet live: ports, directories, names and which process hosts which site.

A fleet of ``N`` sites on base port ``P`` with ``K`` sites per hosting process (decision 0057):

- site ``i`` (``0 <= i < N``) serves its plant on ``P + 3 i``, its PLC on ``P + 3 i + 1`` and
  its supervisor on ``P + 3 i + 2``, so ``tankctl <command> --base-port P+3i`` reaches site
  ``i`` as it would reach a stack of ``tankctl up`` (whose historian would be on ``P + 3 i + 3``:
  a fleet has no historian, and that port is the next site's plant);
- its state, retentive memory and log are in ``<fleet dir>/site-<iii>/`` (``plant-state.json``,
  ``plc-retain.json``, ``supervisor-retain.json``, ``site.log``);
- its name (and so its site identity, decision 0020) is ``<config name>-<iii>``;
- process ``j`` hosts sites ``j K .. min(N, (j+1) K) - 1``: ``ceil(N / K)`` processes, each with
  ``hosts/host-<j>.pid``, ``hosts/host-<j>.log`` and ``hosts/host-<j>.json`` (its sites' states
  and counters, rewritten every :data:`STATUS_PERIOD_S`).

``fleet.json`` in the fleet directory records the layout for ``fleet status``, ``fleet down``
and the hosting processes. Pure: nothing here touches the network; only :meth:`FleetLayout.save`
and :meth:`FleetLayout.load` touch files.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

FLEET_TIERS = ("plant", "plc", "supervisor")
"""The tiers of every site of a fleet, in port order (base + 3 i + index)."""
PORTS_PER_SITE = len(FLEET_TIERS)
STATUS_PERIOD_S = 2.0
"""How often a hosting process rewrites its status file [wall s]."""
LAYOUT_FILE = "fleet.json"
PID_FILE = "fleet.pid"


class FleetError(Exception):
    """A fleet command refuses (one line): bad options, busy ports, no fleet in the directory."""


@dataclass(frozen=True)
class FleetLayout:
    """The fleet's shape; every path and port derives from it (see the module docstring)."""

    fleet_dir: Path
    config_path: Path
    sites: int
    base_port: int
    per_process: int
    speed: float = 1.0
    host: str = "127.0.0.1"
    home: Path | None = None
    base_name: str = "site"

    def __post_init__(self) -> None:
        if self.sites < 1:
            raise FleetError(f"--sites must be at least 1, got {self.sites}")
        if self.per_process < 1:
            raise FleetError(f"--sites-per-process must be at least 1, got {self.per_process}")
        last = self.base_port + PORTS_PER_SITE * self.sites - 1
        if self.base_port < 1 or last > 65535:
            raise FleetError(
                f"--base-port {self.base_port} with --sites {self.sites} needs ports "
                f"{self.base_port}..{last}: they must be within 1..65535"
            )
        if not self.speed > 0:
            raise FleetError(f"--speed must be a positive number, got {self.speed}")

    # ---- sites ----------------------------------------------------------------------------

    def port(self, site: int, tier: str) -> int:
        """The TCP port of ``tier`` of site ``site``: base + 3 site + the tier's index."""
        return self.base_port + PORTS_PER_SITE * site + FLEET_TIERS.index(tier)

    def url(self, site: int, tier: str) -> str:
        shown = f"[{self.host}]" if ":" in self.host else self.host
        return f"opc.tcp://{shown}:{self.port(site, tier)}/tanklab/{tier}"

    @property
    def ports(self) -> list[int]:
        """Every port of the fleet, ascending."""
        return list(range(self.base_port, self.base_port + PORTS_PER_SITE * self.sites))

    def site_name(self, site: int) -> str:
        """Site ``site``'s name: the config's name and its index (a distinct identity per site)."""
        return f"{self.base_name}-{site:03d}"

    def site_dir(self, site: int) -> Path:
        return self.fleet_dir / f"site-{site:03d}"

    # ---- hosting processes ------------------------------------------------------------------

    @property
    def processes(self) -> int:
        """How many hosting processes: ceil(sites / per_process)."""
        return -(-self.sites // self.per_process)

    def hosted(self, process: int) -> range:
        """The sites process ``process`` hosts."""
        first = process * self.per_process
        return range(first, min(self.sites, first + self.per_process))

    @property
    def hosts_dir(self) -> Path:
        return self.fleet_dir / "hosts"

    def host_log(self, process: int) -> Path:
        return self.hosts_dir / f"host-{process}.log"

    def host_pid_file(self, process: int) -> Path:
        return self.hosts_dir / f"host-{process}.pid"

    def host_status_file(self, process: int) -> Path:
        return self.hosts_dir / f"host-{process}.json"

    @property
    def pid_path(self) -> Path:
        """``fleet.pid``: the pid of the ``fleet up`` that runs the fleet."""
        return self.fleet_dir / PID_FILE

    # ---- the layout file --------------------------------------------------------------------

    def save(self) -> None:
        data = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(self).items()}
        self.fleet_dir.mkdir(parents=True, exist_ok=True)
        (self.fleet_dir / LAYOUT_FILE).write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, fleet_dir: Path) -> FleetLayout:
        """The layout ``fleet up`` saved in ``fleet_dir`` (FleetError, one line, when none)."""
        path = fleet_dir / LAYOUT_FILE
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            return cls(
                fleet_dir=fleet_dir,
                config_path=Path(data["config_path"]),
                sites=int(data["sites"]),
                base_port=int(data["base_port"]),
                per_process=int(data["per_process"]),
                speed=float(data["speed"]),
                host=str(data["host"]),
                home=Path(data["home"]) if data.get("home") else None,
                base_name=str(data["base_name"]),
            )
        except FileNotFoundError:
            raise FleetError(
                f"{fleet_dir}: no fleet here (no {LAYOUT_FILE}; `tankctl fleet up` writes it)"
            ) from None
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise FleetError(f"{path}: unreadable fleet layout: {e}") from None
