"""The protocol-fuzz and write-flood generators and oracles of the secured PLC server.

The CI-sized tests in ``tests/robustness/`` and the full-size runs of ``benchmarks/security.py``
(``make bench``) drive the same seeded cases, oracles and post-conditions:

* :mod:`.raw`: raw-transport cases, each on a fresh socket (:data:`RAW_KINDS`);
* :mod:`.typed`: typed cases through authenticated sessions, and the oracles
  :func:`write_must_refuse` and :func:`call_must_refuse`;
* :mod:`.fuzz`: the driver :func:`fuzz_server` and the post-conditions;
* :mod:`.flood`: the write flood and its watchers.
"""

from tanklab_testing.logins import ROLE_OF, Logins, Probe, provision, quiet_disconnect, session
from tanklab_testing.security.draws import pick, random_bytes
from tanklab_testing.security.flood import (
    FLOOD_TARGETS,
    FloodCounts,
    FloodWatch,
    flood_value,
    flood_writes,
    plant_time,
    plc_status,
    status_after_scans,
    watched_flood,
)
from tanklab_testing.security.fuzz import (
    RAW_SHARE,
    SESSION_KINDS,
    PostConditions,
    fuzz_server,
    post_conditions,
    read_scan,
    stored_violations,
)
from tanklab_testing.security.raw import (
    MUST_CLOSE,
    NONE_POLICY_URI,
    RAW_KINDS,
    SECURE_POLICY_URIS,
    RawCase,
    RawOutcome,
    hello,
    open_request,
    raw_case,
    run_raw_case,
)
from tanklab_testing.security.typed import (
    FuzzCounts,
    SessionTargets,
    call_must_refuse,
    random_call,
    random_variant,
    random_write,
    session_case,
    write_must_refuse,
)
from tanklab_testing.sites import HOST, PLC_TAGS, SITE, site_config

__all__ = [
    "FLOOD_TARGETS",
    "HOST",
    "MUST_CLOSE",
    "NONE_POLICY_URI",
    "PLC_TAGS",
    "RAW_KINDS",
    "RAW_SHARE",
    "ROLE_OF",
    "SECURE_POLICY_URIS",
    "SESSION_KINDS",
    "SITE",
    "FloodCounts",
    "FloodWatch",
    "FuzzCounts",
    "Logins",
    "PostConditions",
    "Probe",
    "RawCase",
    "RawOutcome",
    "SessionTargets",
    "call_must_refuse",
    "flood_value",
    "flood_writes",
    "fuzz_server",
    "hello",
    "open_request",
    "pick",
    "plant_time",
    "plc_status",
    "post_conditions",
    "provision",
    "quiet_disconnect",
    "random_bytes",
    "random_call",
    "random_variant",
    "random_write",
    "raw_case",
    "read_scan",
    "run_raw_case",
    "session",
    "session_case",
    "site_config",
    "status_after_scans",
    "stored_violations",
    "watched_flood",
    "write_must_refuse",
]
