"""Map-side and image-side domain models: the scenario schema, terrain and contours, landmarks, the
environment model, the camera emulator, viewframes and their symbolic descriptions, the sensor
simulation, preprocessing, K-GEN keys, the associative memory, the viewframe index and the
landmark detectors. ``models`` imports nothing of ``blackboard`` or ``knowledge_sources``
(tests/models/test_layers.py checks it); its errors derive from :class:`models.errors.ModelError`.

Entry points: :class:`models.world.World` (everything a scenario renders) and
:class:`models.index.ViewframeIndex` (store viewframes, rank camera frames); every default is in
:mod:`models.scenario`.

Glossary (one word per concept, used across the code, messages and results)
---------------------------------------------------------------------------
viewframe
    A view synthesised from the map at a route point: image, depth, landmark mask and symbolic
    description (:class:`models.viewframes.Viewframe`).
viewframe index
    The number of the route point a viewframe belongs to, from 0. It is ``Viewframe.index``, and
    everywhere else a field or variable named ``viewframe`` (``Ranking.viewframes``, a query's
    ``viewframe``, the results' ``viewframe``); ``k`` in formulas. The memory stores each pattern
    under its viewframe index (there are no other "labels").
camera frame
    An image taken by the vehicle's camera (file or simulated), :class:`models.sensor.SensorFrame`,
    posted on the ``sensor_frame`` level; ``frame`` is its number.
camera emulator
    The renderer of views of the environment model (:mod:`models.camera_emulator`). The *camera*
    is the agent that posts the camera frames (:mod:`knowledge_sources.camera`).
world
    A scenario's environment model, camera emulator, route poses, viewframes and camera frames
    (:mod:`models.world`).
pattern
    A preprocessed image, (N, N), zero mean, unit energy (:mod:`models.preprocess`).
memory key
    The noise-like K-GEN key of a pattern (:mod:`models.memory_keys`); not to be confused with a
    blackboard key, the zenoh key expression ``mapinterp/<run>/<level>/<id>``
    (:mod:`blackboard.keys`).
bank
    One holographic memory (:class:`models.associative.HolographicMemory`) holding at most
    ``memory.bank_size`` viewframes; a :class:`~models.associative.BankedMemory` holds several.
shard
    The viewframes one associative indexer agent holds: in a mission ``memory.shard_size``
    consecutive route points (``viewframe index // shard_size == shard``; an indexer started
    without that block size holds ``viewframe index % shards == shard``), in as many banks
    as needed. Rankings of shards and banks merge (their variances are comparable).
index
    :class:`models.index.ViewframeIndex`, the preprocessing + keys + banks + ranking of one set of
    viewframes (a shard in a run); the ``index`` blackboard level says a shard is stored.
ranking
    Stored viewframes ordered by error variance, best first (:class:`models.associative.Ranking`).
landmark, query, answer, position
    A box on the map; a scheduler's question "is landmark L in camera frame F, as seen from
    viewframe V?"; a detector's reply; the decision for one camera frame.
"""
