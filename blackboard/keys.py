"""Key expressions of one run: every key of a run lives under ``mapinterp/<run-id>/``.

Hypotheses: ``mapinterp/<run>/<level>/<id>``. Control traffic uses the verbatim chunk ``@ctl``
(zenoh never matches ``@`` chunks with wildcards), liveliness tokens ``@live``; so a
subscriber to ``mapinterp/<run>/*/*`` sees hypotheses only, and two runs never meet.

Every key expression and selector of a run is built (and taken apart) here:

=============================  ==================================================================
``<root>/<level>/<id>``        a hypothesis (:meth:`RunKeys.hypothesis`)
``<root>/@ctl/status``         agent -> node: idle reports and activity records
``<root>/@ctl/request``        agent -> node queries: join, leave, update, retract
``<root>/@ctl/probe``          node -> agents: quiescence probe
``<root>/@ctl/agent/<name>``   node -> one agent: timeouts of its addressed posts
``<root>/@ctl/node``           the node's liveliness token (up while the run is)
``<root>/@ctl/end``            node -> agents: the run has ended
``<root>/@live/<name>``        an agent's liveliness token
``<key>?agent=..;sent=..``     a read of the store, with what its reader has sent and seen
=============================  ==================================================================
"""

from __future__ import annotations

from blackboard.hypothesis import validate_name

__all__ = ["PREFIX", "RunKeys", "read_parameters"]

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
        self.node_token = f"{self.control}/node"  # the node's liveliness token
        self.run_end = f"{self.control}/end"  # node -> agents: the run has ended
        self.liveliness_all = f"{self.root}/@live/*"

    def hypothesis(self, level: str, hypothesis_id: str) -> str:
        return f"{self.root}/{level}/{hypothesis_id}"

    def level(self, level: str) -> str:
        return f"{self.root}/{level}/*"

    def any_level(self, hypothesis_id: str) -> str:
        """Hypothesis ``hypothesis_id`` on whatever level it is."""
        return f"{self.root}/*/{hypothesis_id}"

    def inbox(self, agent: str) -> str:
        """Node -> one agent: timeouts of its addressed posts, stop."""
        return f"{self.control}/agent/{agent}"

    def liveliness(self, agent: str) -> str:
        return f"{self.root}/@live/{agent}"

    @staticmethod
    def liveliness_agent(key: str) -> str:
        """The agent whose liveliness token ``key`` is."""
        return str(key).rsplit("/", 1)[-1]

    def split(self, key: str) -> tuple[str, str] | None:
        """``(level, id)`` of a hypothesis key of this run, or None."""
        parts = str(key).split("/")
        if len(parts) != 4 or f"{parts[0]}/{parts[1]}" != self.root:
            return None
        return parts[2], parts[3]

    def hypothesis_pattern(self, key: str) -> tuple[str, str] | None:
        """``(level, id)`` of a read's key expression whose chunks are names or ``*``, or None
        for anything else (then match it as a key expression)."""
        parts = str(key).split("/")
        if len(parts) == 4 and all("*" not in p or p == "*" for p in parts[2:]):
            return parts[2], parts[3]
        return None

    @staticmethod
    def read_selector(key: str, *, agent: str, sent: int, seen: dict[str, int]) -> str:
        """A read of ``key``: the node answers once it has received the ``sent`` posts of
        ``agent`` and, of every other sender, the posts ``seen`` by it (:func:`read_parameters`)."""
        after = ",".join(f"{name}:{n}" for name, n in seen.items())
        return f"{key}?agent={agent};sent={sent}" + (f";after={after}" if after else "")


def read_parameters(parameters: object) -> tuple[str, int, dict[str, int]]:
    """``(agent, sent, seen)`` of a read selector's parameters (:meth:`RunKeys.read_selector`);
    ``parameters`` is a zenoh ``Parameters`` or a mapping. Malformed counts read as nothing."""
    get = parameters.get  # type: ignore[attr-defined]
    agent = get("agent") or ""
    try:
        sent = int(get("sent") or 0)
        seen = {
            name: int(n) for name, _, n in (item.rpartition(":") for item in (get("after") or "").split(",") if item)
        }
    except ValueError:
        sent, seen = 0, {}
    return agent, sent, seen
