"""Training loops (TD3 on SMPENV) assembled from TorchRL parts, and evaluation."""
