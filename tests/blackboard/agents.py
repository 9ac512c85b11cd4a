"""Tiny knowledge sources for the blackboard tests; importable, so processes mode can spawn them."""

from __future__ import annotations

import time

import numpy as np

from blackboard.hypothesis import Hypothesis
from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource

__all__ = [
    "Doubler",
    "Echo",
    "Asker",
    "Silent",
    "Failing",
    "Updater",
    "Writer",
    "Recorder",
    "Exclusive",
    "BadSetup",
    "LateCounter",
    "Burster",
    "Tally",
    "Bumper",
    "Rogue",
    "Slow",
    "Booster",
    "Witness",
    "FailingOn",
    "Picky",
    "Big",
]


class Doubler(KnowledgeSource):
    """number {x} -> doubled {x: 2x}, linked to its input."""

    consumes = ("number",)
    produces = ("doubled",)

    def act(self, event: Event, board: Board) -> None:
        if event.kind is EventKind.POSTED:
            h = event.hypothesis
            board.post("doubled", {"x": 2 * h.body["x"], "frame": h.body.get("frame")}, links=(h.id,))


class Echo(KnowledgeSource):
    """doubled -> echo (same body), and answers queries addressed to it."""

    consumes = ("doubled", "query")
    produces = ("echo", "answer")

    def act(self, event: Event, board: Board) -> None:
        h = event.hypothesis
        if event.kind is not EventKind.POSTED:
            return
        if h.level == "query":
            if h.addressed_to == self.name:
                time.sleep(float(self.options.get("delay_s", 0.0)))
                board.post("answer", {"q": h.body.get("q")}, links=(h.id,))
        else:
            board.post("echo", dict(h.body), links=(h.id,))


class Asker(KnowledgeSource):
    """ask {to, q, deadline_s} -> an addressed query; records timeouts as 'timeout' hypotheses."""

    consumes = ("ask",)
    produces = ("query", "timeout")

    def act(self, event: Event, board: Board) -> None:
        body = event.hypothesis.body
        board.post(
            "query",
            {"q": body["q"]},
            addressed_to=body["to"],
            deadline_s=body.get("deadline_s"),
            links=(event.hypothesis.id,),
        )

    def on_timeout(self, hypothesis: Hypothesis, reason: str, board: Board) -> None:
        board.post("timeout", {"reason": reason, "q": hypothesis.body["q"]}, links=(hypothesis.id,))


class Silent(KnowledgeSource):
    """Consumes queries and never answers."""

    consumes = ("query",)


class Failing(KnowledgeSource):
    """Raises in act on every number."""

    consumes = ("number",)
    max_failures = 3

    def act(self, event: Event, board: Board) -> None:
        raise RuntimeError(f"cannot handle {event.hypothesis.body['x']}")


class FailingOn(KnowledgeSource):
    """Doubles numbers, except ``options['x']`` (default 2): raises on it, and goes on."""

    consumes = ("number",)
    produces = ("doubled",)

    def act(self, event: Event, board: Board) -> None:
        x = event.hypothesis.body["x"]
        if x == int(self.options.get("x", 2)):
            raise RuntimeError(f"cannot handle {x}")
        board.post("doubled", {"x": 2 * x})


class Picky(KnowledgeSource):
    """Doubles the numbers whose id ends in an even digit, told by ``wants`` before decoding; the
    others must never reach its ``precondition`` (it raises on them: a counted failure)."""

    consumes = ("number",)
    produces = ("doubled",)

    def wants(self, level: str, hypothesis_id: str) -> bool:
        return int(hypothesis_id[-1]) % 2 == 0

    def precondition(self, event: Event) -> float | None:
        if int(event.hypothesis.id[-1]) % 2:
            raise RuntimeError(f"decoded {event.hypothesis.id}, which wants() declined")
        return 1.0

    def act(self, event: Event, board: Board) -> None:
        board.post("doubled", {"x": 2 * event.hypothesis.body["x"]}, id=f"d-{event.hypothesis.id}")


class Big(KnowledgeSource):
    """On each number x, posts a 'big' hypothesis carrying a (256, 256) float32 array of x."""

    consumes = ("number",)
    produces = ("big",)

    def act(self, event: Event, board: Board) -> None:
        x = event.hypothesis.body["x"]
        board.post("big", {"x": x, "a": np.full((256, 256), float(x), np.float32)}, id=f"big-{x}")


class Updater(KnowledgeSource):
    """On 'target' hypotheses: options['n'] updates, each adding key '<name>-<i>' to the body."""

    consumes = ("target",)
    produces = ("target",)

    def act(self, event: Event, board: Board) -> None:
        if event.kind is EventKind.POSTED:
            for i in range(int(self.options.get("n", 10))):
                board.update(event.hypothesis.id, body={f"{self.name}-{i}": i})


class Writer(KnowledgeSource):
    """On a 'go' hypothesis: options['n'] updates of the hypothesis ``body['target']`` names, each
    adding key '<name>-<i>' (triggered by its own level, so no update of the target obviates it)."""

    consumes = ("go",)
    produces = ("target",)

    def act(self, event: Event, board: Board) -> None:
        for i in range(int(self.options.get("n", 10))):
            board.update(event.hypothesis.body["target"], body={f"{self.name}-{i}": i})


class Recorder(KnowledgeSource):
    """Records the order of its activations in a 'seen' list (precondition rating = body['rating'])."""

    consumes = ("number",)

    def setup(self, board: Board) -> None:
        self.seen: list[tuple[str, int]] = []
        self.existing = [h.body.get("x") for h in board.query("number")]

    def precondition(self, event: Event) -> float | None:
        return event.hypothesis.body.get("rating", 0.0)

    def act(self, event: Event, board: Board) -> None:
        self.seen.append((event.kind.value, event.hypothesis.body.get("x")))
        time.sleep(float(self.options.get("delay_s", 0.0)))


class Exclusive(KnowledgeSource):
    produces = ("position",)
    exclusive = ("position",)


class BadSetup(KnowledgeSource):
    def setup(self, board: Board) -> None:
        raise OSError("model file missing")


class LateCounter(KnowledgeSource):
    """Joins late: in setup, reads the numbers already on the board and posts their sum."""

    produces = ("count",)

    def setup(self, board: Board) -> None:
        existing = board.query("number")
        board.post("count", {"n": len(existing), "sum": sum(h.body["x"] for h in existing)})


class Burster(KnowledgeSource):
    """On 'go' {n, size}: posts n 'item' hypotheses with a payload of size bytes."""

    consumes = ("go",)
    produces = ("item",)

    def act(self, event: Event, board: Board) -> None:
        n, size = int(event.hypothesis.body["n"]), int(event.hypothesis.body.get("size", 16))
        for i in range(n):
            board.post("item", {"i": i, "data": bytes(size)})


class Tally(KnowledgeSource):
    """Counts the items it is activated for (distinct indices) in self.seen."""

    consumes = ("item",)

    def setup(self, board: Board) -> None:
        self.seen: set[int] = set()
        self.activations = 0

    def act(self, event: Event, board: Board) -> None:
        self.activations += 1
        self.seen.add(int(event.hypothesis.body["i"]))


class Bumper(KnowledgeSource):
    """On 'bump': posts a number and at once updates it (the first version becomes obsolete)."""

    consumes = ("bump",)
    produces = ("number",)

    def act(self, event: Event, board: Board) -> None:
        h = board.post("number", {"x": 1, "rating": 0.0})
        board.update(h.id, body={"x": 2})


class Rogue(KnowledgeSource):
    """Posts on a level it did not declare."""

    consumes = ("number",)
    produces = ("doubled",)

    def act(self, event: Event, board: Board) -> None:
        board.post("position", {"x": 0})


class Slow(KnowledgeSource):
    """Takes options['delay_s'] per number."""

    consumes = ("number",)

    def act(self, event: Event, board: Board) -> None:
        time.sleep(float(self.options.get("delay_s", 1.0)))


class Booster(KnowledgeSource):
    """Updates every 'doubled' hypothesis posted by another agent as soon as it sees it."""

    consumes = ("doubled",)
    produces = ("doubled",)

    def act(self, event: Event, board: Board) -> None:
        if event.kind is EventKind.POSTED and event.hypothesis.source != self.name:
            board.update(event.hypothesis.id, body={"boosted": True}, credibility=0.5)


class Witness(KnowledgeSource):
    """number {x} -> truth {frame: x, pose: [x + 0.25, 2x + 0.5, 0.75]}, as the camera posts the
    true poses (a private level)."""

    consumes = ("number",)
    produces = ("truth",)

    def act(self, event: Event, board: Board) -> None:
        if event.kind is EventKind.POSTED:
            x = event.hypothesis.body["x"]
            board.post("truth", {"frame": x, "pose": [x + 0.25, 2 * x + 0.5, 0.75]})
