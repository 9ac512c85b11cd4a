"""The node's store (versions, reads by key expression) and the barrier that holds requests."""

from __future__ import annotations

import pytest

from blackboard.hypothesis import Hypothesis
from blackboard.keys import RunKeys
from blackboard.store import Barrier, Store

KEYS = RunKeys("r1")


def _hyp(level: str, hyp_id: str, t: float) -> Hypothesis:
    return Hypothesis("" + hyp_id, level, "src", 1.0, (), 1, t, {"i": hyp_id})


def _store() -> Store:
    store = Store()
    for level, hyp_id, t in (("a", "x-2", 2.0), ("a", "x-1", 1.0), ("b", "y-1", 1.5), ("b", "x-3", 3.0)):
        store.put(_hyp(level, hyp_id, t), f"data-{hyp_id}".encode())
    return store


def test_hypotheses_oldest_first_by_level() -> None:
    store = _store()
    assert [h.id for h in store.hypotheses()] == ["x-1", "y-1", "x-2", "x-3"]
    assert [h.id for h in store.hypotheses("b")] == ["y-1", "x-3"]
    assert len(store) == 4 and "x-1" in store and "nope" not in store


def test_versions_replace_and_remove() -> None:
    store = _store()
    old = store.get("x-1")
    assert old is not None
    new = old.evolve(body={"j": 1})
    store.put(new, b"v2")
    got = store.get("x-1")
    assert got is not None and got.version == 2 and got.body == {"i": "x-1", "j": 1}
    store.remove("x-1")
    assert store.get("x-1") is None and store.get(7) is None  # non-str ids are simply absent
    with pytest.raises(KeyError):
        store.remove("x-1")


@pytest.mark.parametrize(
    ("key", "ids"),
    [
        ("mapinterp/r1/*/*", ["x-1", "x-2", "x-3", "y-1"]),
        ("mapinterp/r1/a/*", ["x-1", "x-2"]),
        ("mapinterp/r1/*/x-3", ["x-3"]),
        ("mapinterp/r1/b/y-1", ["y-1"]),
        ("mapinterp/r1/b/x-$*", ["x-3"]),  # a partial wildcard: matched as a zenoh key expression
        ("mapinterp/r1/**", ["x-1", "x-2", "x-3", "y-1"]),
        ("mapinterp/r1/c/*", []),
    ],
)
def test_select_answers_reads_with_the_stored_bytes(key: str, ids: list[str]) -> None:
    found = _store().select(KEYS, key)
    assert sorted(h.id for h, _ in found) == ids
    assert all(data == f"data-{h.id}".encode() for h, data in found)


def test_barrier_holds_until_the_posts_seen_have_arrived() -> None:
    barrier = Barrier()
    ran: list[str] = []
    barrier.hold(Barrier.after("a1", 2, {"a2": 1, "bad": "x"}), ran.append, "first")
    barrier.hold(Barrier.after("a1", 0, None), ran.append, "second")  # nothing to wait for
    assert ran == ["second"] and barrier
    barrier.received_from("a1")
    barrier.received_from("a1")
    barrier.release()
    assert ran == ["second"]  # still waiting for a2's post
    barrier.received_from("a2")
    barrier.release()
    assert ran == ["second", "first"] and not barrier


def test_after_takes_the_larger_count_and_ignores_junk() -> None:
    assert Barrier.after("me", 3, {"me": 5, "other": 2, 7: 1, "x": "y"}) == {"me": 5, "other": 2}
    assert Barrier.after("me", 3, ["not", "a", "map"]) == {"me": 3}


def test_a_large_message_is_held_once_compressed_and_decoded_again_when_asked() -> None:
    import dataclasses

    import numpy as np

    from blackboard.codec import decode, encode
    from blackboard.store import KEEP_BYTES_BELOW

    def unpack(data: bytes) -> Hypothesis:
        return Hypothesis.from_record(decode(data)["hyp"])

    # a rendered-looking image (smooth, flat regions) compresses; a random mask does not
    rows = np.arange(120, dtype=np.uint8)[:, None, None]
    image = np.broadcast_to(rows, (120, 160, 3)).copy()
    noise = np.random.default_rng(2).integers(0, 255, (60, 80), dtype=np.uint8)
    big = Hypothesis("vf-1", "viewframe", "renderer", 1.0, (), 1, 1.0, {"image": image, "noise": noise})
    small = _hyp("a", "x-1", 2.0)
    big_data = encode({"op": "post", "hyp": big.to_record(), "sender": "renderer"})
    small_data = encode({"op": "post", "hyp": small.to_record(), "sender": "src"})
    assert len(big_data) >= KEEP_BYTES_BELOW > len(small_data)
    store = Store(unpack=unpack)
    kept_big = store.put(big, big_data, sender="renderer")
    assert store.put(small, small_data, sender="src") == len(small_data)
    assert kept_big < len(big_data) and store.kept_bytes() == kept_big + len(small_data)  # what the run budget counts
    # the image is held once, compressed; no decoded copy of it is kept
    assert store.kept_bytes() < len(small_data) + image.nbytes / 4 + noise.nbytes + 1024
    assert store.decoded_ids() == ["x-1"]
    ((_, again),) = store.select(KEYS, KEYS.hypothesis("viewframe", "vf-1"))
    assert again == big_data  # the read gets the very message that was posted
    got = store.get("vf-1")
    assert got is not None and got == big and type(got) is Hypothesis
    np.testing.assert_array_equal(got.body["image"], image)
    np.testing.assert_array_equal(got.body["noise"], noise)
    # a listing holds no decoded body: it is decoded each time it is read
    listed = store.hypotheses("viewframe")[0]
    assert listed == big and listed.version == 1 and listed.level == "viewframe"
    np.testing.assert_array_equal(listed.body["image"], image)
    assert listed.body["image"] is not listed.body["image"]
    assert "body" not in vars(listed) and big == listed
    # a version made from a listed one is an ordinary hypothesis
    newer = listed.evolve(body={"k": 1})
    assert newer.version == 2 and newer.body["k"] == 1 and set(newer.body) == {"image", "noise", "k"}
    assert dataclasses.replace(listed, credibility=0.5).body["noise"].shape == (60, 80)
    assert store.select(KEYS, KEYS.hypothesis("a", "x-1"))[0][1] is small_data
    keep_all = Store()
    keep_all.put(big, big_data, sender="renderer")
    assert keep_all.kept_bytes() == len(big_data) and keep_all.get("vf-1") is big
