"""The ``geoloc`` command line: one module per command group, registered in :mod:`cli.main`."""
