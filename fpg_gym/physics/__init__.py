"""Physics: the only home of pybullet.

======================  ========================================================================
``pybullet_utils``      DIRECT clients with pybullet's console chatter silenced; ``pybullet_data``
``ragdoll_model``       the 19-capsule body: segment sizes and masses from an anthropometric table
``ragdoll``             the PD-controlled ragdoll (Shum §VII, FPG §7), the floor shift around it
``ragdoll_kinematics``  its bone tree, quaternions, target frames and forward kinematics (numpy)
``ragdoll_build``       its floor, capsules, drives and joints in pybullet (built, removed, placed)
``ragdoll_guards``      its teleport glide and divergence checks
``ragdoll_scene``       what :meth:`~.ragdoll.Ragdoll.render` draws, in a client of its own
``humanoid``            pybullet's DeepMimic humanoid as pybullet loads it (the source and the
                        check of the DeepMimic reader's table,
                        :data:`fpg_gym.io.deepmimic.HUMANOID_TABLE`)
======================  ========================================================================

The simulator's ray casts (:mod:`fpg_gym.simulate.scene`) use pybullet through
:mod:`.pybullet_utils`. The reconstruction layer imports none of this: the ragdoll is injected
(``Reconstructor(graph, ragdoll=Ragdoll)``, or :func:`fpg_gym.methods.ragdoll_factory`).
"""
