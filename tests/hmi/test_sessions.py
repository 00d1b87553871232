"""The HMI's session table (pure): ids, CSRF tokens and the idle timeout on a clock the test sets."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hmi.sessions import TOKEN_BYTES, SessionTable, new_token


def counting_tokens() -> SessionTable:
    counter = itertools.count()
    return SessionTable(idle_timeout_s=900.0, token=lambda: f"tok{next(counter)}")


def test_open_gives_a_fresh_id_and_csrf_token() -> None:
    table = counting_tokens()
    s = table.open("alice", "Operator", now=10.0)
    assert (s.id, s.csrf, s.user, s.role) == ("tok0", "tok1", "alice", "Operator")
    assert (s.created_s, s.last_seen_s, s.sockets) == (10.0, 10.0, 0)
    t = table.open("alice", "Operator", now=11.0)
    assert (t.id, t.csrf) == ("tok2", "tok3")
    assert len(table) == 2 and table.of_user("alice") == [s, t]


def test_real_tokens_are_long_and_distinct() -> None:
    tokens = {new_token() for _ in range(200)}
    assert len(tokens) == 200
    # URL-safe base64 of 32 bytes: ceil(32 * 4 / 3) = 43 characters, no padding.
    assert all(len(t) == 43 and "=" not in t for t in tokens)
    assert TOKEN_BYTES == 32


def test_idle_timeout_counts_from_the_last_request() -> None:
    table = counting_tokens()
    s = table.open("bob", "Observer", now=0.0)
    assert table.get(s.id, now=899.0) is s  # a request at 899 s: idle from there
    assert table.get(s.id, now=1798.9) is s
    assert table.get(s.id, now=2698.9 + 0.1) is None  # 900 s after 1798.9
    assert table.expire(now=2699.0) == [s]
    assert len(table) == 0 and table.get(s.id, now=2699.0) is None


def test_an_open_websocket_keeps_the_session_alive_and_idle_starts_at_its_close() -> None:
    table = counting_tokens()
    s = table.open("carol", "Engineer", now=0.0)
    table.socket_opened(s, now=5.0)
    assert table.expire(now=10_000.0) == []
    assert table.get(s.id, now=10_000.0) is s
    table.socket_closed(s, now=10_100.0)
    assert table.get(s.id, now=10_100.0 + 899.0) is s
    assert table.expire(now=10_999.0 + 900.0) == [s]


def test_expire_takes_only_the_idle_ones_and_close_removes_one() -> None:
    table = counting_tokens()
    old = table.open("a", "Operator", now=0.0)
    new = table.open("b", "Operator", now=500.0)
    assert table.expire(now=900.0) == [old]
    assert table.get(new.id, now=900.0) is new
    assert table.close(new.id) is new and table.close(new.id) is None
    assert len(table) == 0


def test_unknown_and_missing_ids_are_no_session() -> None:
    table = counting_tokens()
    table.open("a", "Operator", now=0.0)
    assert table.get(None, now=1.0) is None
    assert table.get("", now=1.0) is None
    assert table.get("tok1", now=1.0) is None  # a CSRF token is not a session id


def test_csrf_check() -> None:
    table = counting_tokens()
    s = table.open("a", "Operator", now=0.0)
    assert SessionTable.csrf_ok(s, "tok1")
    assert not SessionTable.csrf_ok(s, None)
    assert not SessionTable.csrf_ok(s, "")
    assert not SessionTable.csrf_ok(s, "tok0")  # the session id is not the token
    assert not SessionTable.csrf_ok(s, "tok1 ")


def test_a_repeating_token_source_and_a_bad_timeout_are_errors() -> None:
    table = SessionTable(token=lambda: "same")
    table.open("a", "Operator", now=0.0)
    with pytest.raises(ValueError, match="repeated"):
        table.open("b", "Operator", now=0.0)
    with pytest.raises(ValueError, match="idle_timeout_s"):
        SessionTable(idle_timeout_s=0.0)


@given(st.lists(st.floats(min_value=0.0, max_value=2000.0), min_size=1, max_size=30))
def test_a_session_lives_exactly_while_requests_come_within_the_timeout(gaps: list[float]) -> None:
    """Invariant: after requests at gaps g_1..g_n, the session is alive iff every g_k < timeout."""
    table = SessionTable(idle_timeout_s=900.0)
    s = table.open("a", "Operator", now=0.0)
    now, alive = 0.0, True
    for gap in gaps:
        now += gap
        got = table.get(s.id, now)
        alive = alive and gap < 900.0
        assert (got is s) == alive
