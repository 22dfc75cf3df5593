"""The ``fpg-gym`` sub-commands: one module each (``NAME``, ``HELP``, ``add_arguments``, ``run``).

:func:`fpg_gym.cli.build_parser` imports every command module to build the parser, so a command
imports the library inside ``run()``: ``fpg-gym --help`` and a mistyped option answer in a
fraction of a second instead of loading the graph, pybullet and torch first (the documented
start-up cost that tests/test_architecture.py allows for this package only).
"""
