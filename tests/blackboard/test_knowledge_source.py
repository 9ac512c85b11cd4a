"""Board.post's checks of the level (remembered once passed) over a real zenoh session on loopback."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import zenoh

from blackboard.config import ZenohOptions, open_session, zenoh_config
from blackboard.errors import DeclarationError
from blackboard.keys import RunKeys
from blackboard.zenoh_board import ZenohBoard as Board


@pytest.fixture
def session() -> Iterator[zenoh.Session]:
    session = open_session(zenoh_config(ZenohOptions(), mode="peer"))
    yield session
    session.close()


BAD_LEVELS = {
    "undeclared": ("other", DeclarationError),
    "not a name": ("a/b", ValueError),
    "empty": ("", ValueError),
    "unhashable": (["item"], ValueError),
    "not a str": (7, ValueError),
}


@pytest.mark.parametrize(("level", "error"), BAD_LEVELS.values(), ids=BAD_LEVELS.keys())
def test_post_refuses_a_bad_level_before_and_after_good_posts(
    session: zenoh.Session, run_id: str, level: object, error: type[Exception]
) -> None:
    board = Board(session, RunKeys(run_id), "agent", produces=("item",))
    for attempt in range(3):
        with pytest.raises(error):
            board.post(level, {"i": attempt})  # type: ignore[arg-type]
        assert board.post("item", {"i": attempt}).level == "item"
    assert board.sent == 3


def test_undeclared_producer_may_post_any_valid_level(session: zenoh.Session, run_id: str) -> None:
    board = Board(session, RunKeys(run_id), "user", produces=None)
    assert [board.post(level, {}).level for level in ("a", "b", "a")] == ["a", "b", "a"]
    with pytest.raises(ValueError, match="level"):
        board.post("a b", {})
