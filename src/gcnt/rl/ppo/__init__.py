"""PPO (UNIMAL's algorithm), one module per part; read :mod:`gcnt.rl.ppo.learner` first.

* :mod:`~gcnt.rl.ppo.config`: the ``ppo:`` recipe section (the paper's table 4), torch-free
* :mod:`~gcnt.rl.ppo.learner`: the algorithm and one iteration, read top to bottom
* :mod:`~gcnt.rl.ppo.normalize`: observation normalisation over real limbs, reward scaling
* :mod:`~gcnt.rl.ppo.robot_sampler`: which training robot each env slot runs next

This package imports nothing itself, so that recipes load the config without torch.
"""
