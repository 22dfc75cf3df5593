"""Physics: the only home of pybullet.

=================  ==========================================================================
``pybullet_utils``  DIRECT clients with pybullet's console chatter silenced; ``pybullet_data``
``ragdoll_model``   the 19-capsule body: segment sizes and masses from an anthropometric table
``ragdoll``         the PD-controlled ragdoll (Shum §VII, FPG §7), with the floor shift around it
``humanoid``        pybullet's DeepMimic humanoid as pybullet loads it (the source and the check
                    of the DeepMimic reader's table, :data:`fpg_gym.io.deepmimic.HUMANOID_TABLE`)
=================  ==========================================================================

The simulator's ray casts (:mod:`fpg_gym.simulate.scene`) use pybullet through
:mod:`.pybullet_utils`. The reconstruction layer imports none of this: the ragdoll is injected
(``Reconstructor(graph, ragdoll=Ragdoll)``, or :func:`fpg_gym.methods.ragdoll_factory`).
"""
