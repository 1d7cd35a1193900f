"""SuperTrack (Fussell, Bergamin, Holden; ACM TOG 40(6), 2021): motion tracking by a policy trained through a
learned world model.

Modules: ``config`` (the YAML sections), ``state`` (body states, buffer layout, the semi-implicit Euler integrator,
PD target rotations), ``normalizer`` (fixed statistics of the motion dataset), ``models`` (W and the policy),
``rollout`` (Algorithms 1 and 2), ``losses`` (pure ``(loss, metrics)`` functions), ``actor`` (the policy in the
gym), ``diagnostics`` (open-loop W error), ``learner`` (the :class:`common.train.training.Learner`), ``train`` (the
``train-supertrack`` command).
"""
