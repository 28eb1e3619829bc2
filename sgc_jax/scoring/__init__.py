"""A scoring run (docs/semantics.md §4): the entry points (``api``), the stream that reads clips
ahead of the device and scores them in lanes (``streaming``, ``readers``, ``devices``), across
machines with Ray (``cluster``), the output written as clips finish (``journal``) and the result
model (``result``); and the ``Scorer`` for batches already in memory or on a device, with its
reward (``scorer``, ``reward``; §9).
"""
