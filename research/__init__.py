"""Research tooling around the service: the paper's numerical test, the fleet-sizing experiment, their
figures and markdown reports (``python -m research``). Installed with the ``research`` extra
(``pip install 'sensedispatch[research]'``: matplotlib); the API and the worker never import it."""
