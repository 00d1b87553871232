"""The bounded waits stretch with the load: a hang bound, never a speed target.

A fake clock (each poll advances it by one poll period) and a fake load average stand in for
the machine, so nothing here sleeps or reads the real clock.
"""

from __future__ import annotations

import pytest

from tankctl.testing import waits


class FakeMachine:
    """time.monotonic, time.sleep and os.getloadavg of a machine whose load is ``loads[i]``
    on the i-th read (the last one repeated)."""

    def __init__(self, loads: list[float], cores: int = 2) -> None:
        self.now_s, self.loads, self.reads, self.cores = 0.0, loads, 0, cores

    def monotonic(self) -> float:
        return self.now_s

    def sleep(self, dt_s: float) -> None:
        self.now_s += dt_s

    def getloadavg(self) -> tuple[float, float, float]:
        load = self.loads[min(self.reads, len(self.loads) - 1)]
        self.reads += 1
        return (load, load, load)


@pytest.fixture
def machine(monkeypatch: pytest.MonkeyPatch, request: pytest.FixtureRequest) -> FakeMachine:
    fake = FakeMachine(request.param)
    monkeypatch.setattr(waits.time, "monotonic", fake.monotonic)
    monkeypatch.setattr(waits.time, "sleep", fake.sleep)
    monkeypatch.setattr(waits.os, "getloadavg", fake.getloadavg)
    monkeypatch.setattr(waits.os, "sched_getaffinity", lambda _pid: {0, 1})
    return fake


@pytest.mark.parametrize("machine", [[0.5]], indirect=True)
def test_on_an_idle_machine_the_bound_is_the_deadline(machine: FakeMachine) -> None:
    with pytest.raises(AssertionError, match=r"^timed out after 10 s waiting for the pumps$"):
        waits.wait_until_sync(lambda: False, 10.0, what="the pumps", poll_s=0.5)
    assert machine.now_s == 10.0  # 20 polls of 0.5 s; load 0.5 on 2 cores stretches nothing


@pytest.mark.parametrize("machine", [[8.0]], indirect=True)
def test_load_8_on_2_cores_stretches_the_bound_4_times(machine: FakeMachine) -> None:
    with pytest.raises(AssertionError, match=r"after 40 s \(a 10\.0 s bound x 4\.0 for the load\)"):
        waits.wait_until_sync(lambda: False, 10.0, poll_s=0.5)
    assert machine.now_s == 40.0


@pytest.mark.parametrize("machine", [[2.0, 6.0]], indirect=True)
def test_load_that_rises_during_the_wait_lengthens_it(machine: FakeMachine) -> None:
    # Load 2.0 on 2 cores stretches nothing: the wait ends at 10 s (the 6.0 is never read).
    with pytest.raises(AssertionError, match=r"after 10 s waiting"):
        waits.wait_until_sync(lambda: False, 10.0, poll_s=0.5)
    assert machine.now_s == 10.0
    # Load 4.0 when the 10 s are up (x2: go on), 6.0 when the 20 s are up (x3: go on to 30 s).
    machine.now_s, machine.reads, machine.loads = 0.0, 0, [4.0, 6.0]
    with pytest.raises(AssertionError, match=r"after 30 s \(a 10\.0 s bound x 3\.0"):
        waits.wait_until_sync(lambda: False, 10.0, poll_s=0.5)
    assert machine.now_s == 30.0


@pytest.mark.parametrize("machine", [[8.0]], indirect=True)
def test_a_condition_that_comes_true_returns_at_once(machine: FakeMachine) -> None:
    calls = []

    def on_the_third_poll() -> bool:
        calls.append(machine.now_s)
        return len(calls) == 3

    waits.wait_until_sync(on_the_third_poll, 10.0, poll_s=0.5)
    assert calls == [0.0, 0.5, 1.0]


@pytest.mark.parametrize("machine", [[1.0], [3.0]], indirect=True)
def test_hang_bound_and_load_stretch(machine: FakeMachine) -> None:
    expected = max(1.0, machine.loads[0] / 2)
    assert waits.load_stretch() == expected
    assert waits.hang_bound(240.0) == 240.0 * expected
