"""TD3 (SMPENV's algorithm), one module per part; read :mod:`gcnt.rl.td3.learner` first.

* :mod:`~gcnt.rl.td3.config`: the ``td3:`` recipe section (the paper's table 2), torch-free
* :mod:`~gcnt.rl.td3.learner`: the algorithm, its update schedule and the learner's two steps
* :mod:`~gcnt.rl.td3.loss`: the loss math as pure functions on per-limb Q tensors
* :mod:`~gcnt.rl.td3.replay`: per-robot replay rings in one storage
* :mod:`~gcnt.rl.td3.tensor_chain`: the policy chains called on plain tensors (update and collection)
* :mod:`~gcnt.rl.td3.stacked`, :mod:`~gcnt.rl.td3.stacked_loop`: several seeds trained in one
  process, their updates under one ``torch.vmap``

This package imports nothing itself, so that recipes load the config without torch.
"""
