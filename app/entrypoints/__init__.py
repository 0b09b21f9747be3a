"""The ways into the service from outside the process: ``python -m app COMMAND`` (``cli``, which hands
``import-city``, ``replay``, ``demo`` and ``worker`` to their own modules), the HTTP server (``server``:
uvicorn with a header deadline and a connection cap) and the service run in a thread of this process
(``serve``), with the replay client the ``replay`` and ``demo`` commands drive it with (``replay_client``).

Why ``entrypoints``: it is the name of the room in cosmicpython's layout, which this shell follows
(ports, adapters, use cases, one ``bootstrap``); it says what the modules have in common (each is where a
process, a command or a request from outside begins) where ``cli`` would leave out the server and ``main``
would say nothing. Nothing here holds the service's logic: each module reads its options, asks
``app.bootstrap`` for the parts and runs them.
"""
