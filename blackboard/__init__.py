"""DOORS-style distributed blackboard over Eclipse Zenoh, with a recorded trace.

Modules (imported explicitly; importing ``blackboard`` itself loads nothing heavy, because
:mod:`blackboard.errors` is imported by every command):

- :mod:`blackboard.errors`: :class:`BlackboardError`, the root of the blackboard's exceptions

- :mod:`blackboard.hypothesis`: :class:`Hypothesis`, name validation (names are key chunks)
- :mod:`blackboard.keys`: key expressions of a run, ``mapinterp/<run-id>/<level>/<id>``
- :mod:`blackboard.codec`: msgpack with numpy arrays (no pickle) and size limits
- :mod:`blackboard.config`: loopback-only zenoh configuration, ``--connect/--listen/--zenoh-config``
- :mod:`blackboard.knowledge_source`: :class:`KnowledgeSource`, the :class:`Board` protocol, :class:`Event`
- :mod:`blackboard.zenoh_board`: :class:`ZenohBoard`, the distributed board (an agent's zenoh session)
- :mod:`blackboard.memory_board`: :class:`MemoryBlackboard`, agents in one thread without zenoh (tests)
- :mod:`blackboard.agent`: one knowledge source's session, agenda and worker thread
- :mod:`blackboard.agent_host`: ``python -m blackboard.agent_host`` (processes mode)
- :mod:`blackboard.node`: store, versions, trace, liveness, addressed-post timeouts, quiescence
- :mod:`blackboard.runtime`: :class:`Runtime`, the node plus its agents, run until quiescence
- :mod:`blackboard.trace`, :mod:`blackboard.trace_view`: the trace file and its pure views
"""
