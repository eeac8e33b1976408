"""Stream input and output around the engine: sources, sinks, buffering, the sessions that drive
:class:`~mocapdb.runtime.engine.Engine` over them, and the track files they write.

The algorithms (retrieval, the temporal choice, refinement, the take's world) live one level up in
:mod:`mocapdb.runtime` and never import from here. Users of the streams import from
:mod:`mocapdb.runtime.stream.transport` (:func:`~mocapdb.runtime.stream.transport.open_source`,
:func:`~mocapdb.runtime.stream.transport.open_sink`).
"""
