"""Typed fuzz cases through an authenticated session: random values (pure), the oracles that say
which write or call the contract must refuse (written independently of ``tanklab_io.ua``'s
checks), and one request per case.
"""

from __future__ import annotations

import math
import struct
import uuid
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
from asyncua import Client, ua

from tanklab.config import SiteConfig
from tanklab.tags import DataType, Role, Tag
from tanklab_testing.security.draws import pick, random_bytes
from tanklab_testing.security.raw import MUST_CLOSE, RawOutcome
from tanklab_testing.sites import SITE
from tanklab_testing.stats import Summary

VT = ua.VariantType
_INT_RANGES: dict[ua.VariantType, tuple[int, int]] = {
    VT.SByte: (-(2**7), 2**7 - 1),
    VT.Byte: (0, 2**8 - 1),
    VT.Int16: (-(2**15), 2**15 - 1),
    VT.UInt16: (0, 2**16 - 1),
    VT.Int32: (-(2**31), 2**31 - 1),
    VT.UInt32: (0, 2**32 - 1),
    VT.Int64: (-(2**63), 2**63 - 1),
    VT.UInt64: (0, 2**64 - 1),
}
_OTHER_TYPES = (
    VT.Boolean,
    VT.String,
    VT.DateTime,
    VT.Guid,
    VT.ByteString,
    VT.NodeId,
    VT.StatusCode,
    VT.QualifiedName,
    VT.LocalizedText,
    VT.ExtensionObject,
    VT.Null,
)
VARIANT_OF = {
    DataType.DOUBLE: VT.Double,
    DataType.INT32: VT.Int32,
    DataType.UINT32: VT.UInt32,
    DataType.BOOLEAN: VT.Boolean,
    DataType.STRING: VT.String,
    DataType.DOUBLE_ARRAY: VT.Double,
}


def _number(rng: np.random.Generator, tag: Tag | None) -> float:
    """A float that probes the edges: non-finite, extreme, inside / just outside EURange, enum."""
    lo, hi = tag.eu_range if tag is not None and tag.eu_range is not None else (-1.0, 1.0)
    span = hi - lo or 1.0
    choices: list[Callable[[], float]] = [
        lambda: math.nan,
        lambda: math.inf,
        lambda: -math.inf,
        lambda: 0.0,
        lambda: -0.0,
        lambda: 5e-324,
        lambda: 1e308,
        lambda: -1e308,
        lambda: float(rng.uniform(lo, hi)),
        lambda: float(rng.uniform(lo, hi)),
        lambda: hi + span * 1e-9 + 1e-12,
        lambda: lo - span * 1e-9 - 1e-12,
        lambda: hi * 10 + 1.0,
        lambda: float(int(rng.integers(-1, 5))),
        lambda: float(rng.normal() * 10.0 ** int(rng.integers(-8, 9))),
    ]
    return float(pick(rng, choices)())


def _integer(rng: np.random.Generator, vt: ua.VariantType, tag: Tag | None) -> int:
    lo, hi = _INT_RANGES[vt]
    pool = [lo, hi, 0, 1, 2, 3, 4, -1, int(rng.integers(-5, 6))]
    if tag is not None and tag.eu_range is not None:
        pool += [int(tag.eu_range[0]), int(tag.eu_range[1]), int(tag.eu_range[1]) + 1]
    x = int(pick(rng, pool))
    return min(max(x, lo), hi)


def _scalar(rng: np.random.Generator, vt: ua.VariantType, tag: Tag | None) -> Any:
    if vt in _INT_RANGES:
        return _integer(rng, vt, tag)
    if vt == VT.Double:
        return _number(rng, tag)
    if vt == VT.Float:
        x = _number(rng, tag)
        return x if not math.isfinite(x) or abs(x) < 3e38 else math.copysign(3e38, x)
    if vt == VT.Boolean:
        return bool(rng.random() < 0.5)
    if vt == VT.String:
        return pick(rng, ("", "0.4", "AUTO", "REMOTE", "nan", "\x00", "ü" * 40, "x" * 4000))
    if vt == VT.DateTime:
        return datetime(1601, 1, 2, tzinfo=UTC) + timedelta(days=float(rng.uniform(0, 3_000_000)))
    if vt == VT.Guid:
        return uuid.UUID(bytes=random_bytes(rng, 16))
    if vt == VT.ByteString:
        return random_bytes(rng, int(rng.integers(0, 64)))
    if vt == VT.NodeId:
        return ua.NodeId(int(rng.integers(0, 100_000)), int(rng.integers(0, 4)))
    if vt == VT.StatusCode:
        return ua.StatusCode(int(pick(rng, (0, 0x40000000, 0x80000000, ua.StatusCodes.BadOutOfRange))))
    if vt == VT.QualifiedName:
        return ua.QualifiedName("SP", int(rng.integers(0, 4)))
    if vt == VT.LocalizedText:
        return ua.LocalizedText(pick(rng, ("AUTO", "REMOTE", "0.4")))
    if vt == VT.ExtensionObject:
        return ua.Range(Low=_number(rng, tag), High=_number(rng, tag))
    return None


def random_variant(rng: np.random.Generator, tag: Tag | None) -> ua.Variant:
    """A Variant of a random type; biased toward the tag's own type so values reach the
    range checks. Scalars, 1-D arrays (0 to 5 items) and 2 x 2 matrices."""
    r = rng.random()
    if tag is not None and tag.data_type is not None and r < 0.45:
        vt = VARIANT_OF[tag.data_type]
    elif r < 0.75:
        vt = pick(rng, (VT.Double, VT.Float, VT.Int32, VT.UInt32, VT.Int64, VT.Boolean))
    else:
        vt = pick(rng, (*_INT_RANGES, *_OTHER_TYPES, VT.Float, VT.Double))
    if vt == VT.Null:
        return ua.Variant()
    shape = rng.random()
    if shape < 0.8:
        return ua.Variant(_scalar(rng, vt, tag), vt)
    if shape < 0.93:
        n = int(rng.integers(0, 6))
        return ua.Variant([_scalar(rng, vt, tag) for _ in range(n)], vt, is_array=True)
    matrix = [[_scalar(rng, vt, tag) for _ in range(2)] for _ in range(2)]
    return ua.Variant(matrix, vt, Dimensions=[2, 2], is_array=True)


def _scalar_of(v: ua.Variant, want: ua.VariantType) -> Any:
    """The scalar value of ``v`` if it is a scalar of type ``want``, else None."""
    if v is None or v.VariantType != want or v.is_array or isinstance(v.Value, list) or v.Dimensions:
        return None
    return v.Value


def write_must_refuse(tag: Tag | None, role: Role, wv: ua.WriteValue) -> bool:
    """Whether the contract requires the server to refuse this write (any refusal status).

    Written from the architecture's rules, not from ``tanklab_io.ua``'s code: only the Value of a
    writable tag, by one of its writers, as a scalar of the tag's type, finite, inside EURange,
    a member of its enumeration, inside a restricted role's allowed set, with a Good (or absent)
    status and no index range may be stored. Everything else (properties, standard nodes,
    unknown nodes, other attributes) must be refused.
    """
    if tag is None or tag.kind != "variable" or tag.data_type is None:
        return True
    if wv.AttributeId != ua.AttributeIds.Value or not tag.writable or role not in tag.writers:
        return True
    if wv.IndexRange:
        return True
    dv = wv.Value
    if dv is None or (dv.StatusCode is not None and not dv.StatusCode.is_good()):
        return True
    x = _scalar_of(dv.Value, VARIANT_OF[tag.data_type])
    if x is None or tag.data_type == DataType.DOUBLE_ARRAY:
        return True
    if isinstance(x, float) and not math.isfinite(x):
        return True
    if tag.eu_range is not None and not tag.eu_range[0] <= x <= tag.eu_range[1]:
        return True
    if tag.enum is not None and int(x) not in {int(m) for m in tag.enum}:
        return True
    allowed = dict(tag.restricted).get(role)
    return allowed is not None and int(x) not in allowed


def _gain_box(site: SiteConfig, loop: str) -> tuple[tuple[float, float], ...] | None:
    assert site.plc is not None
    for lp in site.plc.loops:
        if lp.name == loop and lp.gain_box is not None:
            box = lp.gain_box
            return (tuple(box.kp), tuple(box.ki), tuple(box.kd))  # type: ignore[return-value]
    return None


def call_must_refuse(
    tag: Tag | None, role: Role, args: Sequence[ua.Variant], site: SiteConfig = SITE
) -> bool:
    """Whether the contract requires the server to refuse this method call.

    Refused: a node that is not a method of the contract, a role not among its writers, the wrong
    number of arguments, an argument not a scalar Double, a gain that is not finite or outside
    the loop's gain box. (An admissible SetGains may still be refused with BadInvalidState while
    the supervisor is not trusted: that is the PLC's state, not the contract.)
    """
    if tag is None or tag.kind != "method" or role not in tag.writers:
        return True
    if len(args) != len(tag.inputs):
        return True
    values = []
    for arg, v in zip(tag.inputs, args, strict=True):
        x = _scalar_of(v, VARIANT_OF[arg.data_type])
        if x is None:
            return True
        values.append(x)
    if tag.name == "SetGains":
        if not all(math.isfinite(x) for x in values):
            return True
        box = _gain_box(site, tag.path.split(".")[1])
        if box is not None and not all(lo <= x <= hi for x, (lo, hi) in zip(values, box, strict=True)):
            return True
    return False


@dataclass
class SessionTargets:
    """What a fuzz session aims at: NodeIds of every PLC tag, its properties, standard and
    unknown nodes; the tag behind each NodeId (None for the others)."""

    idx: int
    variables: list[tuple[ua.NodeId, Tag | None]]
    methods: list[tuple[ua.NodeId, ua.NodeId, Tag | None]]  # (object, method, tag)

    @classmethod
    def build(cls, idx: int, tags: Sequence[Tag]) -> SessionTargets:
        variables: list[tuple[ua.NodeId, Tag | None]] = []
        methods: list[tuple[ua.NodeId, ua.NodeId, Tag | None]] = []
        objects = sorted({t.parent for t in tags})
        for t in tags:
            node = ua.NodeId(t.path, idx)
            if t.kind == "method":
                methods.append((ua.NodeId(t.parent, idx), node, t))
                # the same method on another object, and the method id as a variable
                methods.append((ua.NodeId(objects[0], idx), node, t))
                variables.append((node, None))
                continue
            variables.append((node, t))
            if t.eu_range is not None:
                variables.append((ua.NodeId(f"{t.path}.EURange", idx), None))
            if t.enum is not None:
                variables.append((ua.NodeId(f"{t.path}.EnumStrings", idx), None))
            if t.unit is not None:
                variables.append((ua.NodeId(f"{t.path}.EngineeringUnits", idx), None))
        for std in (
            ua.ObjectIds.Server_NamespaceArray,
            ua.ObjectIds.Server_ServerStatus_State,
            ua.ObjectIds.Server_ServerStatus_CurrentTime,
            ua.ObjectIds.Server_ServiceLevel,
            ua.ObjectIds.Server_ServerCapabilities_MaxBrowseContinuationPoints,
        ):
            variables.append((ua.NodeId(std), None))
        variables.append((ua.NodeId("PLC.NoSuchNode", idx), None))
        variables.append((ua.NodeId(123456, 7), None))
        variables.append((ua.NodeId(objects[0], idx), None))  # an object, not a variable
        methods.append(
            (ua.NodeId(ua.ObjectIds.Server), ua.NodeId(ua.ObjectIds.Server_GetMonitoredItems), None)
        )
        methods.append((ua.NodeId("PLC.NoSuchObject", idx), ua.NodeId("PLC.NoSuchMethod", idx), None))
        return cls(idx, variables, methods)


_OTHER_ATTRIBUTES = (
    ua.AttributeIds.DisplayName,
    ua.AttributeIds.Description,
    ua.AttributeIds.AccessLevel,
    ua.AttributeIds.UserAccessLevel,
    ua.AttributeIds.DataType,
    ua.AttributeIds.ValueRank,
    ua.AttributeIds.BrowseName,
    ua.AttributeIds.NodeId,
    ua.AttributeIds.Historizing,
)


def random_write(rng: np.random.Generator, targets: SessionTargets) -> tuple[ua.WriteValue, Tag | None]:
    """One WriteValue: a random target (half the time a writable tag, so that values reach the
    range checks and some are stored), mostly its Value, a random Variant and DataValue."""
    writable = [(n, t) for n, t in targets.variables if t is not None and t.writable]
    node, tag = pick(rng, writable if writable and rng.random() < 0.5 else targets.variables)
    wv = ua.WriteValue()
    wv.NodeId = node
    wv.AttributeId = ua.AttributeIds.Value if rng.random() < 0.9 else pick(rng, _OTHER_ATTRIBUTES)
    if rng.random() < 0.05:
        wv.IndexRange = pick(rng, ("0", "1:2", "0:0", "x", "-1"))
    status = ua.StatusCode(ua.StatusCodes.Good)
    if rng.random() < 0.15:
        status = ua.StatusCode(
            int(
                pick(
                    rng,
                    (
                        0x40000000,
                        0x80000000,
                        ua.StatusCodes.BadOutOfRange,
                        ua.StatusCodes.UncertainLastUsableValue,
                    ),
                )
            )
        )
    stamp = datetime(2000, 1, 1, tzinfo=UTC) + timedelta(days=float(rng.uniform(0, 20_000)))
    wv.Value = ua.DataValue(
        Value=random_variant(rng, tag),
        StatusCode=status,
        SourceTimestamp=stamp if rng.random() < 0.5 else None,
        ServerTimestamp=stamp if rng.random() < 0.1 else None,
    )
    return wv, tag


def random_call(rng: np.random.Generator, targets: SessionTargets) -> tuple[ua.CallMethodRequest, Tag | None]:
    """One method call: a random (object, method), 0 to 5 random arguments (often three
    Doubles probing the gain box)."""
    obj, method, tag = pick(rng, targets.methods)
    req = ua.CallMethodRequest()
    req.ObjectId = obj
    req.MethodId = method
    if tag is not None and tag.name == "SetGains" and rng.random() < 0.6:
        box = _gain_box(SITE, tag.path.split(".")[1]) or ((0.0, 1.0),) * 3
        args = []
        for lo, hi in box:
            x = float(rng.uniform(lo, hi)) if rng.random() < 0.7 else _number(rng, None)
            args.append(ua.Variant(x, VT.Double))
        req.InputArguments = args
    else:
        req.InputArguments = [random_variant(rng, None) for _ in range(int(rng.integers(0, 6)))]
    return req, tag


@dataclass
class FuzzCounts:
    """Cases per kind, the server's answers, and the violations of the oracles."""

    cases: Counter[str] = field(default_factory=Counter)
    statuses: Counter[str] = field(default_factory=Counter)
    closed: Counter[str] = field(default_factory=Counter)
    replies: Counter[str] = field(default_factory=Counter)
    close_s: list[float] = field(default_factory=list)
    failed: Counter[str] = field(default_factory=Counter)
    violations: list[str] = field(default_factory=list)
    admissible_refused: int = 0
    findings: Counter[str] = field(default_factory=Counter)
    """Accepted requests that break OPC UA but not the tanklab contract (not violations)."""

    def merge_raw(self, out: RawOutcome) -> None:
        self.cases[out.kind] += 1
        if out.failed:  # keyed with the reason: a report (or a failing test) says why
            self.failed[f"{out.kind}: {out.failed}"] += 1
            return
        if out.closed:
            self.closed[out.kind] += 1
            if math.isfinite(out.close_s):
                self.close_s.append(out.close_s)
        self.replies[f"{out.kind}:{out.reply or '-'}"] += 1
        if out.kind in MUST_CLOSE and not out.closed:
            self.violations.append(f"raw {out.kind}: connection left open (reply {out.reply or 'none'})")

    def as_dict(self) -> dict[str, Any]:
        return {
            "cases": dict(self.cases),
            "statuses": dict(self.statuses.most_common()),
            "closed": dict(self.closed),
            "replies": dict(sorted(self.replies.items())),
            "close_s": Summary.of(self.close_s).__dict__,
            "failed": dict(self.failed),
            "violations": list(self.violations),
            "admissible_refused": self.admissible_refused,
            "findings": dict(self.findings),
        }


def _status_name(code: ua.StatusCode | int) -> str:
    value = code.value if isinstance(code, ua.StatusCode) else int(code)
    return ua.StatusCode(value).name


async def _guarded(counts: FuzzCounts, kind: str, coro: Any) -> Any:
    """Run one session request; a service fault counts as a refusal by its status."""
    try:
        return await coro
    except ua.UaStatusCodeError as e:
        counts.statuses[_status_name(e.code)] += 1
        return None
    except (TimeoutError, ConnectionError) as e:
        counts.failed[kind] += 1
        counts.violations.append(f"{kind}: the server did not answer ({type(e).__name__})")
        return None


async def session_case(
    client: Client, role: Role, targets: SessionTargets, rng: np.random.Generator, counts: FuzzCounts
) -> None:
    """One typed case through ``client`` (acting as ``role``), judged by the oracles."""
    r = rng.random()
    if r < 0.7:
        kind = "write"
        items = [random_write(rng, targets) for _ in range(int(pick(rng, (1, 1, 1, 2, 4))))]
        params = ua.WriteParameters(NodesToWrite=[wv for wv, _ in items])
        counts.cases[kind] += 1
        try:
            results = await _guarded(counts, kind, client.uaclient.write(params))
        except (struct.error, OverflowError, ValueError, TypeError) as e:  # not encodable: not sent
            counts.failed[f"{kind} (not encodable: {type(e).__name__})"] += 1
            return
        for (wv, tag), status in zip(items, results or [], strict=False):
            counts.statuses[_status_name(status)] += 1
            refuse = write_must_refuse(tag, role, wv)
            if status.is_good() and refuse:
                what = tag.path if tag is not None else wv.NodeId.to_string()
                counts.violations.append(
                    f"write {what} attr {wv.AttributeId} = {wv.Value.Value!r} by {role.value}: accepted"
                )
            elif not status.is_good() and not refuse:
                counts.admissible_refused += 1
    elif r < 0.9:
        kind = "call"
        req, tag = random_call(rng, targets)
        counts.cases[kind] += 1
        try:
            results = await _guarded(counts, kind, client.uaclient.call([req]))
        except (struct.error, OverflowError, ValueError, TypeError) as e:
            counts.failed[f"{kind} (not encodable: {type(e).__name__})"] += 1
            return
        for res in results or []:
            status = res.StatusCode
            counts.statuses[_status_name(status)] += 1
            refuse = call_must_refuse(tag, role, req.InputArguments)
            if status.is_good() and refuse:
                what = tag.path if tag is not None else req.MethodId.to_string()
                counts.violations.append(f"call {what}({req.InputArguments!r}) by {role.value}: accepted")
            elif not status.is_good() and not refuse:
                counts.admissible_refused += 1
            if status.is_good() and tag is not None and req.ObjectId.Identifier != tag.parent:
                # OPC UA Part 4 wants BadMethodInvalid; asyncua dispatches on the MethodId alone.
                counts.findings[f"{tag.path} called through {req.ObjectId.Identifier}: Good"] += 1
    elif r < 0.96:
        kind = "node_management"
        counts.cases[kind] += 1
        await _node_management_case(client, role, targets, rng, counts)
    else:
        kind = "subscription"
        counts.cases[kind] += 1
        await _subscription_case(client, targets, rng, counts)


async def _node_management_case(
    client: Client, role: Role, targets: SessionTargets, rng: np.random.Generator, counts: FuzzCounts
) -> None:
    """AddNodes, DeleteNodes, AddReferences or DeleteReferences: no tanklab role may change the
    address space, so any success is a violation."""
    node, _ = pick(rng, targets.variables)
    parent = ua.NodeId("PLC.LIC1", targets.idx)
    which = int(rng.integers(4))
    if which == 0:
        item = ua.AddNodesItem()
        item.RequestedNewNodeId = ua.NodeId(f"PLC.Fuzz{int(rng.integers(1_000_000))}", targets.idx)
        item.BrowseName = ua.QualifiedName("Fuzz", targets.idx)
        item.NodeClass = ua.NodeClass.Variable
        item.ParentNodeId = parent
        item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasComponent)
        item.TypeDefinition = ua.NodeId(ua.ObjectIds.BaseDataVariableType)
        attrs = ua.VariableAttributes()
        attrs.Value = ua.Variant(1.0, VT.Double)
        item.NodeAttributes = attrs
        results = await _guarded(counts, "node_management", client.uaclient.add_nodes([item]))
        codes = [r.StatusCode for r in results or []]
    elif which == 1:
        item = ua.DeleteNodesItem(NodeId=node, DeleteTargetReferences=True)
        params = ua.DeleteNodesParameters(NodesToDelete=[item])
        codes = await _guarded(counts, "node_management", client.uaclient.delete_nodes(params)) or []
    elif which == 2:
        ref = ua.AddReferencesItem(
            SourceNodeId=parent,
            ReferenceTypeId=ua.NodeId(ua.ObjectIds.HasComponent),
            IsForward=True,
            TargetNodeId=node,
            TargetNodeClass=ua.NodeClass.Variable,
        )
        codes = await _guarded(counts, "node_management", client.uaclient.add_references([ref])) or []
    else:
        ref = ua.DeleteReferencesItem(
            SourceNodeId=parent,
            ReferenceTypeId=ua.NodeId(ua.ObjectIds.HasComponent),
            IsForward=True,
            TargetNodeId=node,
            DeleteBidirectional=True,
        )
        codes = await _guarded(counts, "node_management", client.uaclient.delete_references([ref])) or []
    for code in codes:
        status = code if isinstance(code, ua.StatusCode) else ua.StatusCode(int(code))
        counts.statuses[status.name] += 1
        if status.is_good():
            counts.violations.append(
                f"node management ({which}) on {node.to_string()} by {role.value}: accepted"
            )


async def _subscription_case(
    client: Client, targets: SessionTargets, rng: np.random.Generator, counts: FuzzCounts
) -> None:
    """A subscription with absurd parameters and monitored items, created then deleted."""
    params = ua.CreateSubscriptionParameters()
    params.RequestedPublishingInterval = float(pick(rng, (0.0, -1.0, math.nan, 1e-3, 1e12)))
    params.RequestedLifetimeCount = int(pick(rng, (0, 1, 2**32 - 1)))
    params.RequestedMaxKeepAliveCount = int(pick(rng, (0, 1, 2**32 - 1)))
    params.MaxNotificationsPerPublish = int(pick(rng, (0, 2**32 - 1)))
    params.PublishingEnabled = True
    params.Priority = int(rng.integers(0, 256))
    result = await _guarded(
        counts, "subscription", client.uaclient.create_subscription(params, lambda *_: None)
    )
    if result is None:
        return
    counts.statuses["Good"] += 1
    items = []
    for _ in range(int(rng.integers(1, 4))):
        node, _tag = pick(rng, targets.variables)
        req = ua.MonitoredItemCreateRequest()
        req.ItemToMonitor = ua.ReadValueId(NodeId=node, AttributeId=ua.AttributeIds.Value)
        req.MonitoringMode = ua.MonitoringMode.Reporting
        mp = ua.MonitoringParameters()
        mp.ClientHandle = int(rng.integers(0, 2**32))
        mp.SamplingInterval = float(pick(rng, (0.0, -1.0, math.nan, 1e-6, 1e12)))
        mp.QueueSize = int(pick(rng, (0, 1, 2**32 - 1)))
        mp.DiscardOldest = bool(rng.random() < 0.5)
        req.RequestedParameters = mp
        items.append(req)
    mparams = ua.CreateMonitoredItemsParameters(
        SubscriptionId=result.SubscriptionId,
        TimestampsToReturn=ua.TimestampsToReturn.Both,
        ItemsToCreate=items,
    )
    created = await _guarded(counts, "subscription", client.uaclient.create_monitored_items(mparams))
    for res in created or []:
        counts.statuses[_status_name(res.StatusCode)] += 1
    await _guarded(counts, "subscription", client.uaclient.delete_subscriptions([result.SubscriptionId]))
