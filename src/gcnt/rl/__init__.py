"""Training: the shared run loop and what every algorithm uses, one folder per algorithm.

* :mod:`~gcnt.rl.loop`: the run loop (seeding, resume, collector, metrics, checkpoints, evaluation)
* :mod:`~gcnt.rl.algorithm`: the algorithm seam, what an algorithm gives the run loop
* :mod:`~gcnt.rl.td3`, :mod:`~gcnt.rl.ppo`: the two algorithms
* :mod:`~gcnt.rl.factories`: ``make_env`` / ``make_net`` from a recipe
* :mod:`~gcnt.run.directory`: run directories and atomic checkpoints
* :mod:`~gcnt.rl.evaluate`: evaluation on any robots (zero-shot included)
* :mod:`~gcnt.rl.accelerate`: the ``compile:`` switches (torch.compile, CUDA graphs, AMP)
"""
