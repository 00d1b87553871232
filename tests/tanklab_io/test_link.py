"""The tiers' client link (``tanklab_io.ua_client.Link``): backoff schedule, failure reports, recovery.

The backoff schedule is a pure function, checked with hand-computed values and a Hypothesis
bound. The link's waiting is on an injected clock that only moves when the test moves it, so no
test sleeps: a refused connection is a real one (a closed loopback port), a recovery is a real
plant server started on that port.
"""

from __future__ import annotations

import asyncio
import logging
import math
import random

import pytest
from hypothesis import given
from hypothesis import strategies as st

from helpers import ROOT, free_port, identity, server_security, wait_until
from plant_sim.runtime import run_plant
from plc_emulator.link import FieldLink
from supervisor.link import PlcLink
from tanklab.clock import VirtualClock
from tanklab.config import load_site
from tanklab.errors import LinkError
from tanklab.tags import (
    LINK_STATUS_ITEMS,
    link_status_paths,
    plant_tags,
    plc_tags,
    supervisor_tags,
    tags_by_path,
)
from tanklab_io.ua_client import BACKOFF_CAP_S, Link, backoff_delay, describe_error, request_deadline
from tanklab_io.ua_security import client_setup

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")


class FixedRandom(random.Random):
    """A random source whose ``random()`` is always ``u``."""

    def __init__(self, u: float) -> None:
        super().__init__(0)
        self.u = u

    def random(self) -> float:
        return self.u


# --------------------------------------------------------------------------------------------
# The schedule (pure)
# --------------------------------------------------------------------------------------------


def test_backoff_by_hand_without_and_with_jitter() -> None:
    # d_k = min(5, 0.2 * 2**k): 0.2, 0.4, 0.8, 1.6, 3.2, 5, 5, ...
    no_jitter = [backoff_delay(k, FixedRandom(0.0)) for k in range(8)]
    assert no_jitter == pytest.approx([0.2, 0.4, 0.8, 1.6, 3.2, 5.0, 5.0, 5.0])
    # u = 0.5, jitter 0.5: delay = d_k * (1 - 0.25)
    assert [backoff_delay(k, FixedRandom(0.5)) for k in (0, 3, 9)] == pytest.approx([0.15, 1.2, 3.75])
    # u -> 1: the floor d_k * (1 - jitter)
    assert backoff_delay(2, FixedRandom(0.999999)) == pytest.approx(0.4, abs=1e-6)
    # other parameters: base 1 s, factor 3, cap 20 s, full jitter, u = 0.25
    got = [backoff_delay(k, FixedRandom(0.25), base_s=1, factor=3, cap_s=20, jitter=1) for k in range(4)]
    assert got == pytest.approx([0.75, 2.25, 6.75, 15.0])
    # a constant schedule (factor 1) and an attempt number far past any float power
    assert backoff_delay(50, FixedRandom(0.0), factor=1.0) == pytest.approx(0.2)
    assert backoff_delay(10**6, FixedRandom(0.0)) == BACKOFF_CAP_S


@given(
    attempt=st.integers(0, 5000),
    base=st.floats(1e-3, 10),
    factor=st.floats(1, 10),
    cap_over_base=st.floats(1, 1000),
    jitter=st.floats(0, 1),
    seed=st.integers(0, 2**32 - 1),
)
def test_backoff_stays_between_the_jittered_floor_and_the_capped_exponential(
    attempt: int, base: float, factor: float, cap_over_base: float, jitter: float, seed: int
) -> None:
    cap = base * cap_over_base
    d = backoff_delay(attempt, random.Random(seed), base_s=base, factor=factor, cap_s=cap, jitter=jitter)
    try:
        exponential = base * factor**attempt
    except OverflowError:
        exponential = math.inf
    top = min(cap, exponential)
    assert top * (1 - jitter) * (1 - 1e-12) <= d <= top * (1 + 1e-12)
    assert 0 < d <= cap * (1 + 1e-12)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"attempt": -1},
        {"base_s": 0.0},
        {"factor": 0.5},
        {"cap_s": 0.1},
        {"jitter": 1.5},
        {"base_s": math.nan},
    ],
)
def test_backoff_refuses_bad_parameters(kwargs: dict[str, float]) -> None:
    args = {"attempt": 0, **kwargs}
    attempt = int(args.pop("attempt"))
    with pytest.raises(ValueError):
        backoff_delay(attempt, random.Random(0), **args)


def test_errors_are_described_by_class_and_message() -> None:
    assert describe_error(TimeoutError()) == "TimeoutError"
    assert describe_error(ConnectionRefusedError(111, "Connect call failed")) == (
        "ConnectionRefusedError: [Errno 111] Connect call failed"
    )


def test_every_tier_link_has_its_status_nodes() -> None:
    plc = tags_by_path(plc_tags(SITE))
    sup = tags_by_path(supervisor_tags(SITE))
    for paths, tags in (
        (link_status_paths("PLC.Status.PlantLink"), plc),
        (link_status_paths("Supervisor.PlcLink"), sup),
    ):
        assert set(paths) == set(LINK_STATUS_ITEMS)
        assert all(p in tags and not tags[p].writable for p in paths.values())


# --------------------------------------------------------------------------------------------
# The link on an injected clock
# --------------------------------------------------------------------------------------------


def _link(url: str, clock: VirtualClock, u: float = 0.5) -> Link:
    tags = tags_by_path(plant_tags(SITE))
    return Link(
        url,
        {"Plant.Sim.Time": tags["Plant.Sim.Time"]},
        name="field",
        setup=client_setup(identity(tier="plc")),
        timeout_s=4.0,
        clock=clock,
        rng=FixedRandom(u),
        failure_level=logging.WARNING,  # as the tiers' links
    )


async def test_refused_attempts_are_logged_counted_and_spaced_by_the_backoff(
    caplog: pytest.LogCaptureFixture,
) -> None:
    port = free_port()  # nothing listens there
    url = f"opc.tcp://127.0.0.1:{port}/tanklab/plant"
    clock = VirtualClock()
    link = _link(url, clock)
    caplog.set_level(logging.WARNING, logger="tanklab_io.ua_client")
    assert not await link.ensure()
    assert link.attempts == 1
    assert link.last_error.startswith("ConnectionRefusedError: ")
    assert link.retry_delay_s == pytest.approx(0.15)  # backoff_delay(0, u=0.5)
    (line,) = [r.getMessage() for r in caplog.records]  # one line per attempt, nothing else
    assert line == (
        f"field link: connection attempt 1 to {url} failed: {link.last_error}; next attempt in 0.15 s"
    )
    # Not due yet: no attempt, no new line.
    clock.advance(0.14)
    assert not await link.ensure()
    assert link.attempts == 1 and len(caplog.records) == 1
    clock.advance(0.01)
    assert not await link.ensure()
    assert link.attempts == 2 and link.retry_delay_s == pytest.approx(0.3)
    for k in range(2, 8):
        clock.advance(link.retry_delay_s)
        assert not await link.ensure()
        assert link.attempts == k + 1
    assert link.retry_delay_s == pytest.approx(0.75 * BACKOFF_CAP_S)
    assert len(caplog.records) == 8
    paths = link_status_paths("PLC.Status.PlantLink")
    assert link.status("PLC.Status.PlantLink") == {
        paths["Attempts"]: 8,
        paths["Connects"]: 0,
        paths["LastError"]: link.last_error,
        paths["RetryDelay"]: pytest.approx(3.75),
    }


async def test_a_failing_setup_is_reported_with_its_class_and_message(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async def setup(client: object) -> None:
        raise PermissionError("pki/private/plc.pem: Permission denied")

    clock = VirtualClock()
    tags = tags_by_path(plant_tags(SITE))
    link = Link(
        "opc.tcp://127.0.0.1:1/x",
        {"Plant.Sim.Time": tags["Plant.Sim.Time"]},
        name="field",
        setup=setup,
        clock=clock,
    )
    caplog.set_level(logging.INFO, logger="tanklab_io.ua_client")
    assert not await link.ensure()
    assert link.last_error == "PermissionError: pki/private/plc.pem: Permission denied"
    (record,) = caplog.records
    assert "PermissionError: pki/private/plc.pem: Permission denied" in record.getMessage()
    assert "opc.tcp://127.0.0.1:1/x" in record.getMessage()
    assert record.levelno == logging.INFO  # a plain Link (a CLI probe) reports at INFO


def test_the_tiers_links_report_failed_attempts_as_warnings() -> None:
    async def setup(client: object) -> None:
        return None

    field = FieldLink(SITE, "opc.tcp://127.0.0.1:1/tanklab/plant", setup=setup)
    plc = PlcLink(SITE, "opc.tcp://127.0.0.1:1/tanklab/plc", setup=setup)
    assert field.link.failure_level == plc.link.failure_level == logging.WARNING


async def test_a_recovered_link_resets_its_backoff_and_a_lost_one_retries_at_once() -> None:
    port = free_port()
    url = f"opc.tcp://127.0.0.1:{port}/tanklab/plant"
    clock = VirtualClock()
    link = _link(url, clock)
    for _ in range(3):
        clock.advance(link.retry_delay_s)
        assert not await link.ensure()
    assert link.attempts == 3
    stop, ready = asyncio.Event(), asyncio.Event()
    task = asyncio.create_task(
        run_plant(
            SITE, host="127.0.0.1", port=port, security=server_security(), speed=1.0, stop=stop, ready=ready
        )
    )
    try:
        await wait_until(ready.is_set, 20, what="plant server ready")
        assert not await link.ensure()  # the clock has not moved: no attempt is due
        assert link.attempts == 3
        clock.advance(link.retry_delay_s)
        assert await link.ensure()
        assert (link.attempts, link.connects, link.retry_delay_s) == (0, 1, 0.0)
        assert link.last_error.startswith("ConnectionRefusedError")  # why it was down, kept
        (dv,) = await link.read(["Plant.Sim.Time"])
        assert dv.StatusCode.is_good()
    finally:
        stop.set()
        await asyncio.wait_for(task, 20)
    # The server is gone: the request fails once, the reconnection is tried at once (no clock
    # move) and fails, then the schedule starts again from its first delay.
    with pytest.raises(LinkError):
        await link.read(["Plant.Sim.Time"])
    assert link.last_error.startswith("read: ")
    assert not await link.ensure()
    assert link.attempts == 1 and link.retry_delay_s == pytest.approx(0.15)
    await link.close()


async def test_a_client_says_which_side_ended_its_connection(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "tanklab_io.ua_client")
    port = free_port()
    url = f"opc.tcp://127.0.0.1:{port}/tanklab/plant"
    link = _link(url, VirtualClock())
    stop, ready = asyncio.Event(), asyncio.Event()
    task = asyncio.create_task(
        run_plant(
            SITE, host="127.0.0.1", port=port, security=server_security(), speed=1.0, stop=stop, ready=ready
        )
    )
    try:
        await wait_until(ready.is_set, 20, what="plant server ready")
        assert await link.ensure()
    finally:
        stop.set()
        await asyncio.wait_for(task, 20)

    def said() -> bool:
        return any("connection lost, the socket closed" in r.getMessage() for r in caplog.records)

    await wait_until(said, 20, what="the client's connection-lost warning")
    await link.close()


# --------------------------------------------------------------------------------------------
# The request deadline: asyncua's wait_for racing ours (CancelledWithResultError)
# --------------------------------------------------------------------------------------------


async def _answer_in_the_iteration_the_deadline_fires(deadline: object) -> str:
    """asyncua's own wait_for (wait_for2, as its requests use) inside ``deadline(0)``: the
    deadline's cancel and the answer land in the same loop iteration, no wall time involved."""
    from asyncua.common.utils import wait_for as asyncua_wait_for

    loop = asyncio.get_running_loop()
    answer: asyncio.Future[str] = loop.create_future()
    async with deadline(0):  # type: ignore[operator]
        loop.call_soon(answer.set_result, "answer")  # right after the deadline's own callback
        return await asyncua_wait_for(answer, 10.0)
    raise AssertionError("unreachable")


async def test_asyncio_timeout_alone_lets_the_race_escape_as_a_cancellation() -> None:
    # The defect request_deadline exists for: the subclass of CancelledError that asyncua raises
    # is not turned into TimeoutError, so it ends the task that made the request.
    with pytest.raises(asyncio.CancelledError) as info:
        await _answer_in_the_iteration_the_deadline_fires(asyncio.timeout)
    assert type(info.value) is not asyncio.CancelledError
    asyncio.current_task().uncancel()  # type: ignore[union-attr]


async def test_the_request_deadline_turns_the_race_into_a_timeout() -> None:
    with pytest.raises(TimeoutError):
        await _answer_in_the_iteration_the_deadline_fires(request_deadline)


async def test_the_request_deadline_passes_a_stop_through_as_a_cancellation() -> None:
    started = asyncio.Event()

    async def request() -> None:
        async with request_deadline(60.0):
            started.set()
            await asyncio.Event().wait()

    task = asyncio.create_task(request())
    await started.wait()
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert task.cancelled()


async def test_the_request_deadline_returns_what_the_request_returns() -> None:
    async def request() -> int:
        return 42

    async with request_deadline(60.0):
        value = await request()
    assert value == 42
