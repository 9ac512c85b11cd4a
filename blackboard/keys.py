"""Key expressions of one run: every key of a run lives under ``mapinterp/<run-id>/``.

Hypotheses: ``mapinterp/<run>/<level>/<id>``. Control traffic uses the verbatim chunk ``@ctl``
(zenoh never matches ``@`` chunks with wildcards), liveliness tokens ``@live``; so a
subscriber to ``mapinterp/<run>/*/*`` sees hypotheses only, and two runs never meet.
"""

from __future__ import annotations

from blackboard.hypothesis import validate_name

__all__ = ["RunKeys"]

PREFIX = "mapinterp"


class RunKeys:
    """Key expressions of run ``run_id``.

    Example::

        >>> RunKeys("r1").hypothesis("answer", "h-1")
        'mapinterp/r1/answer/h-1'
    """

    def __init__(self, run_id: str) -> None:
        self.run_id = validate_name(run_id, "run id")
        self.root = f"{PREFIX}/{run_id}"
        self.all_hypotheses = f"{self.root}/*/*"
        self.control = f"{self.root}/@ctl"
        self.status = f"{self.control}/status"  # agent -> node: idle reports, activity records
        self.request = f"{self.control}/request"  # agent -> node queries: join, update, retract
        self.probe = f"{self.control}/probe"  # node -> agents: quiescence probe
        self.liveliness_all = f"{self.root}/@live/*"

    def hypothesis(self, level: str, hypothesis_id: str) -> str:
        return f"{self.root}/{level}/{hypothesis_id}"

    def level(self, level: str) -> str:
        return f"{self.root}/{level}/*"

    def inbox(self, agent: str) -> str:
        """Node -> one agent: timeouts of its addressed posts, stop."""
        return f"{self.control}/agent/{agent}"

    def liveliness(self, agent: str) -> str:
        return f"{self.root}/@live/{agent}"

    def split(self, key: str) -> tuple[str, str] | None:
        """``(level, id)`` of a hypothesis key of this run, or None."""
        parts = str(key).split("/")
        if len(parts) != 4 or f"{parts[0]}/{parts[1]}" != self.root:
            return None
        return parts[2], parts[3]
