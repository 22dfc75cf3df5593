"""Physics: the only home of pybullet.

=================  ==========================================================================
``pybullet_utils``  DIRECT clients with pybullet's console chatter silenced; ``pybullet_data``
``ragdoll_model``   the 19-capsule body: segment sizes and masses from an anthropometric table
``ragdoll``         the PD-controlled ragdoll (Shum §VII, FPG §7) and the floor shift around it
=================  ==========================================================================

The simulator's ray casts (:mod:`fpg_gym.simulate.scene`) and the DeepMimic reader's forward
kinematics (:mod:`fpg_gym.io.deepmimic`) use pybullet through :mod:`.pybullet_utils`.
"""
