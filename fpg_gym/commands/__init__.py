"""Sub-commands of the ``fpg-gym`` command line (see :mod:`fpg_gym.cli`)."""
